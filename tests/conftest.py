"""Shared fixtures: the real LiDAR samples beside the checkout and small synthetic frames."""

from __future__ import annotations

from pathlib import Path

import pytest
from _real import real_data_dir

from lwbench import Frame, SensorModel, get_sensor
from lwbench.testing import cylinder_scan

REAL_DATA = real_data_dir()


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"real LiDAR samples not found at {REAL_DATA} (set LWBENCH_REAL_DATA)")
    return REAL_DATA


@pytest.fixture
def tiny_sensor() -> SensorModel:
    # 4 beams x 8 azimuth steps: small enough to compute metrics by hand.
    return SensorModel("tiny", (-3.0, -1.0, 1.0, 3.0), 45.0, 0.1, 20.0, 10.0)


@pytest.fixture
def vlp16_frame() -> Frame:
    """A synthetic VLP-16 scan of a cylinder wall (radius 5 m), every ray a return."""
    return cylinder_scan(5.0, get_sensor("vlp16"))


@pytest.fixture(scope="session")
def kitti_folder(tmp_path_factory) -> Path:
    """A small dataset the tests write themselves, so the run -> store -> leaderboard path is
    tested on every machine: three off-grid VLP-16 room scans in KITTI layout (velodyne/*.bin,
    times.txt, sensor.json), no poses."""
    from lwbench.io import write_kitti_sequence
    from lwbench.testing import room_scan

    out = tmp_path_factory.mktemp("kitti") / "seq"
    frames = [room_scan(get_sensor("vlp16"), seed=11, index=i, dropout=0.02) for i in range(3)]
    return write_kitti_sequence(frames, out)
