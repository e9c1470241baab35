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
