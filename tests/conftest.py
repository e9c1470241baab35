"""Shared fixtures: the real LiDAR samples beside the checkout and small synthetic frames."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from lwbench import Frame, SensorModel, get_sensor

REPO = Path(__file__).resolve().parents[1]
REAL_DATA = Path(os.environ.get("LWBENCH_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"real LiDAR samples not found at {REAL_DATA} (set LWBENCH_REAL_DATA)")
    return REAL_DATA


def cell_centre_points(sensor: SensorModel, ranges: np.ndarray) -> np.ndarray:
    """Points exactly on the centre ray of each cell with a positive range."""
    return sensor.unproject(ranges)


@pytest.fixture
def tiny_sensor() -> SensorModel:
    # 4 beams x 8 azimuth steps: small enough to compute metrics by hand.
    return SensorModel("tiny", (-3.0, -1.0, 1.0, 3.0), 45.0, 0.1, 20.0, 10.0)


@pytest.fixture
def vlp16_frame() -> Frame:
    """A synthetic VLP-16 scan of a cylinder wall (radius 5 m), every ray a return."""
    sensor = get_sensor("vlp16")
    dirs = sensor.ray_directions()
    horiz = np.linalg.norm(dirs[..., :2], axis=-1)
    ranges = (5.0 / horiz).astype(np.float32)
    pts = cell_centre_points(sensor, ranges)
    return Frame(pts, sensor, index=0)
