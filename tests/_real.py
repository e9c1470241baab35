"""Where the real LiDAR samples are: one rule, used by the ``real_data`` fixture and by the
benchmark scripts run as programs.

``LWBENCH_REAL_DATA`` when set, else ``shared/data/real`` beside the checkout (where this
project's CI keeps them). A user's clone has neither: real-data tests then skip, and every test
that must run everywhere uses data the tests generate.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def real_data_dir() -> Path:
    return Path(os.environ.get("LWBENCH_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


def kitti_frame0() -> Path:
    """KITTI odometry 00 frame 0 (124,668 points, xyz only) among the samples."""
    return real_data_dir() / "kitti00_frames0-1" / "000000.bin"
