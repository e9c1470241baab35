"""Generated scans with what real recordings hold and clean simulations lack.

Used by the codec conformance test and the codec tests, so every codec meets them on every
machine (the real samples under ``shared/data/real`` are an extra, not a requirement):

- :func:`with_exact_duplicates`: a scan in which some returns are bit-for-bit copies of others
  (the issue's nuScenes frames: 34,752 points, 25,532 distinct);
- :func:`hdl32_ring_frame`: a 32-beam spinning scan with a per-point ``ring`` field, whose lasers
  sit off the nominal beam table (per-laser calibration, as in real HDL-32E data), and whose
  sensor model is derived the way the file loaders derive it from a scan with a ring field
  (:meth:`SensorModel.from_points` with ``ring``: per-ring medians).
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, SensorModel

#: HDL-32E nominal elevations: -30.67 to +10.67 degrees in 4/3 degree steps.
HDL32_NOMINAL = tuple(float(e) for e in np.linspace(-30.67, 10.67, 32))

#: Where the generated sensor writes a firing that got no return: one fixed point a few
#: hundredths of a millimetre from the origin (nuScenes keeps such rays as points with a radius
#: below 1e-4 m). Every such ray is then an exact copy of every other.
NO_RETURN = (3e-5, -2e-5, 4e-5)


def with_exact_duplicates(frame: Frame, share: float = 0.25, seed: int = 0) -> Frame:
    """``frame`` plus exact copies of ``share`` of its points, shuffled in; the per-point
    attributes are copied with their points."""
    rng = np.random.default_rng(seed)
    n = len(frame)
    idx = np.concatenate([np.arange(n), rng.integers(0, n, int(round(share * n)))])
    return frame.subset(idx[rng.permutation(len(idx))])


def hdl32_ring_frame(seed: int = 0, firings: int = 1086) -> Frame:
    """A 32-beam scan of a street (ground 1.8 m below the sensor, building fronts 8-25 m away in
    some directions, open sky elsewhere), ``firings`` x 32 points in firing order with a ring
    field, like a nuScenes ``LIDAR_TOP`` sweep.

    Each laser is up to 0.15 degrees off its nominal elevation. Rays that hit nothing are written
    as :data:`NO_RETURN`, so the upper rings, which mostly see the sky, are mostly that one point
    and their per-ring medians coincide: the derived beam table has several beams at one
    elevation. Both are what ordinary real scans do to codecs that assume clean data.
    """
    rng = np.random.default_rng(seed)
    el = np.radians(np.asarray(HDL32_NOMINAL) + rng.uniform(-0.15, 0.15, 32))[:, None]
    az = -np.pi + (np.arange(firings) + rng.uniform(0, 1, (32, 1))) * (2 * np.pi / firings)
    wall_r = 8 + 17 * (0.5 + 0.5 * np.sin(3 * az + seed))
    wall_top = np.where(np.sin(4 * az) > 0.3, 4.0, 0.0) - 1.8  # building fronts in some sectors
    with np.errstate(divide="ignore"):
        t_ground = np.where(el < 0, 1.8 / np.sin(-el), np.inf)
    t_wall = wall_r / np.cos(el)
    t_wall = np.where(t_wall * np.sin(el) < wall_top, t_wall, np.inf)
    t = np.minimum(t_ground, t_wall)
    hit = np.isfinite(t)
    t = np.where(hit, t, 0.0) * (1 + rng.normal(0, 0.002, t.shape))
    dirs = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)
    pts = dirs * t[..., None]
    pts[~hit] = NO_RETURN
    points = pts.transpose(1, 0, 2).reshape(-1, 3).astype(np.float32)  # firing-major, as drivers write
    ring = np.tile(np.arange(32, dtype=np.uint16), firings)
    intensity = rng.uniform(0, 100, len(points)).astype(np.float32)
    sensor = SensorModel.from_points(points, ring=ring, rate_hz=20.0, name="derived")
    return Frame(points, sensor, index=0, intensity=intensity, ring=ring)
