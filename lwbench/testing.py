"""Small synthetic scans for tests -- lwbench's and a plugin author's own.

The simulator casts every ray through a range-image cell centre; real sensors do not (firings
drift against any fixed grid, each laser has its own azimuth and elevation offset, ranges are
noisy). :func:`room_scan` produces scans of the second kind in a few milliseconds, with no
ray-casting library, so a test can check that a codec or metric does not depend on where cell
edges fall.
"""

from __future__ import annotations

import numpy as np

from lwbench.frame import Frame
from lwbench.geometry import unit_directions
from lwbench.sensor import SensorModel

__all__ = ["room_scan", "ROOM_HALF_EXTENT"]

# A 6 m x 4 m x 2.4 m room centred on the sensor: walls, floor and ceiling; every ray hits.
ROOM_HALF_EXTENT = (3.0, 2.0, 1.2)


def _room_range(directions: np.ndarray, half: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        t = np.where(np.abs(directions) > 1e-12, half / np.abs(directions), np.inf)
    return t.min(axis=1)


def room_scan(
    sensor: SensorModel,
    *,
    seed: int = 0,
    off_grid: bool = True,
    noise: float = 0.01,
    dropout: float = 0.0,
    index: int = 0,
    with_ring: bool = False,
    half_extent: tuple[float, float, float] = ROOM_HALF_EXTENT,
) -> Frame:
    """One sweep of ``sensor`` inside a box room.

    ``off_grid`` makes it look like a real sensor: each beam fires at its own azimuth phase
    (0..1 of a step, as Ouster's per-beam azimuth offsets), its elevation deviates from the
    table by up to a tenth of the beam spacing, and the firing clock drifts by a fraction of a
    step over the sweep. ``off_grid=False`` casts through the cell centres like the simulator.
    ``noise`` is the range noise (m, Gaussian), ``dropout`` the share of rays with no return.
    """
    rng = np.random.default_rng([seed, index])
    n_b, n_a = sensor.shape
    el = np.repeat(sensor.elevations_rad[:, None], n_a, axis=1)
    cols = np.broadcast_to(np.arange(n_a, dtype=np.float64), (n_b, n_a))
    phase = np.full((n_b, 1), 0.5)
    if off_grid:
        gaps = np.diff(sensor.elevations_rad) if n_b > 1 else np.array([sensor.azimuth_step_rad])
        spacing = float(np.median(gaps))
        el = el + rng.uniform(-0.1, 0.1, (n_b, 1)) * spacing
        phase = rng.uniform(0.0, 1.0, (n_b, 1))
        drift = np.linspace(0.0, rng.uniform(0.1, 0.4), n_a)[None, :]
        cols = cols + drift
    az = -np.pi + (cols + phase) * sensor.azimuth_step_rad
    dirs = unit_directions(az, el).reshape(-1, 3)
    r = _room_range(dirs, np.asarray(half_extent, dtype=np.float64))
    r = r + rng.normal(0.0, noise, len(r)) if noise > 0 else r
    keep = (r > sensor.min_range) & (r < sensor.max_range)
    if dropout > 0:
        keep &= rng.random(len(r)) >= dropout
    pts = (dirs * r[:, None])[keep].astype(np.float32)
    ring = np.repeat(np.arange(n_b), n_a)[keep].astype(np.uint16) if with_ring else None
    return Frame(pts, sensor, index=index, ring=ring, intensity=np.full(len(pts), 0.5, np.float32))
