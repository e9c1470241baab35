"""Synthetic scans in closed form: what the conformance kit, the fuzzer and warm-ups run on.

Every scan here is intersected in closed form (no ray-casting library), costs milliseconds and
is exactly reproducible from its seed:

- :func:`room_scan` -- a box room; with ``off_grid`` (the default) it looks like a real sensor's
  scan: firings drift against any fixed grid and each laser has its own azimuth and elevation
  offset, so a test can check that a codec or metric does not depend on where cell edges fall
  (the simulator casts every ray through a range-image cell centre; real sensors do not);
- :func:`tunnel_scan` -- an elliptic mine tunnel with a floor and rough walls (VSGP's setting);
- :func:`cylinder_scan` -- a smooth vertical wall around the sensor, optionally only half of it;
- :func:`hdl32_ring_scan` -- a 32-beam street scan in firing order with a ring field and
  no-return filler points, like a nuScenes sweep;
- :func:`check_frames` -- the kit's scans, named: what every codec must handle.

They are public through :mod:`lwbench.testing`; core code (a base process warming its decoder
up, the fuzzer's seed payloads) takes them from here, not from the test kit.
"""

from __future__ import annotations

import functools

import numpy as np

from lwbench.frame import Frame
from lwbench.geometry import spherical, unit_directions
from lwbench.sensors.model import SensorModel, get_sensor

__all__ = [
    "HDL32_NOMINAL",
    "NO_RETURN",
    "ROOM_HALF_EXTENT",
    "check_frames",
    "cylinder_scan",
    "hdl32_ring_scan",
    "room_scan",
    "tunnel_ranges",
    "tunnel_scan",
    "with_exact_duplicates",
]

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


def _ellipse_hit(d: np.ndarray, origin: np.ndarray, a: float, b: float) -> np.ndarray:
    """Distance along each unit ray ``d`` from ``origin`` (inside) to ``y^2/a^2 + z^2/b^2 = 1``."""
    dy, dz = d[..., 1], d[..., 2]
    oy, oz = origin[1], origin[2]
    qa = dy**2 / a**2 + dz**2 / b**2
    qb = 2 * (oy * dy / a**2 + oz * dz / b**2)
    qc = oy**2 / a**2 + oz**2 / b**2 - 1.0  # < 0 inside
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-qb + np.sqrt(np.maximum(qb**2 - 4 * qa * qc, 0.0))) / (2 * qa)
    return np.where(qa > 1e-12, t, np.inf)


def tunnel_ranges(
    sensor: SensorModel,
    *,
    seed: int = 0,
    half_width: float = 2.5,
    half_height: float = 2.2,
    floor: bool = True,
    roughness: float = 0.04,
    noise: float = 0.01,
    dropout: float = 0.01,
) -> np.ndarray:
    """Range image ``(n_beams, n_azimuth)`` of an elliptic tunnel; 0 = no return.

    The tunnel runs along a random heading; the sensor sits off-centre; the wall's radius is
    modulated by a few seeded sinusoids in direction space (rock roughness, relative amplitude
    ``roughness``), and each range gets Gaussian noise ``noise`` (m) and random dropouts.
    Returns beyond the sensor's max range are zeros, like a real sensor's.
    """
    rng = np.random.default_rng(seed)
    a = half_width * rng.uniform(0.85, 1.15)
    b = half_height * rng.uniform(0.85, 1.15)
    heading = rng.uniform(-np.pi, np.pi)
    origin = np.array([0.0, rng.uniform(-0.3, 0.3) * a, rng.uniform(-0.2, 0.1) * b])
    dirs = sensor.ray_directions()  # (B, A, 3), sensor frame
    c, s = np.cos(heading), np.sin(heading)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # sensor -> tunnel frame
    d = dirs @ rot.T
    t = _ellipse_hit(d, origin, a, b)
    if floor:
        floor_z = -0.8 * b
        with np.errstate(divide="ignore", invalid="ignore"):
            tf = np.where(d[..., 2] < -1e-6, (floor_z - origin[2]) / d[..., 2], np.inf)
        t = np.minimum(t, tf)
    _, az, el = spherical(d.reshape(-1, 3))
    az, el = az.reshape(t.shape), el.reshape(t.shape)
    bump = np.zeros_like(t)
    for _ in range(6):
        ka, ke = rng.integers(1, 9), rng.uniform(0, 12)
        bump += np.sin(ka * az + ke * el + rng.uniform(0, 2 * np.pi)) / 6
    t = t * (1 + roughness * bump) + rng.normal(0.0, noise, t.shape)
    t[(t < sensor.min_range) | (t > sensor.max_range) | ~np.isfinite(t)] = 0.0
    t[rng.random(t.shape) < dropout] = 0.0
    return t.astype(np.float32)


def tunnel_scan(seed: int = 0, sensor: SensorModel | None = None, **kwargs: float) -> Frame:
    """A :class:`Frame` of :func:`tunnel_ranges` (VLP-16 at 10 m unless a sensor is given)."""
    sensor = sensor or get_sensor("vlp16")
    ranges = tunnel_ranges(sensor, seed=seed, **kwargs)
    return Frame(sensor.unproject(ranges), sensor, index=seed, pose=np.eye(4))


def cylinder_scan(radius: float = 4.0, sensor: SensorModel | None = None, half: bool = False) -> Frame:
    """A noiseless vertical cylinder wall of ``radius`` around the sensor (smooth surface).

    ``half=True`` keeps only the azimuths in ``[0, pi)``: the other half of the scan is free
    space, which the decoder's variance filter must recognise.
    """
    sensor = sensor or get_sensor("vlp16")
    el = sensor.elevations_rad[:, None]
    az = sensor.azimuths_rad()[None, :]
    ranges = np.broadcast_to(radius / np.cos(el), (sensor.n_beams, sensor.n_azimuth)).copy()
    if half:
        ranges[:, (az[0] < 0)] = 0.0
    ranges[ranges > sensor.max_range] = 0.0
    return Frame(sensor.unproject(ranges.astype(np.float32)), sensor, pose=np.eye(4))


#: HDL-32E nominal elevations: -30.67 to +10.67 degrees in 4/3 degree steps.
HDL32_NOMINAL = tuple(float(e) for e in np.linspace(-30.67, 10.67, 32))

#: Where :func:`hdl32_ring_scan` writes a firing that got no return: one fixed point a few
#: hundredths of a millimetre from the origin (nuScenes keeps such rays as points with a radius
#: below 1e-4 m). Every such ray is then an exact copy of every other.
NO_RETURN = (3e-5, -2e-5, 4e-5)

#: The no-return marker of older nuScenes LIDAR_TOP files: one point about 0.19 m from the sensor
#: (elevation -3.68 deg), written for every ray that got no return.
NUSCENES_NO_RETURN = (0.1893, 0.0084, -0.0122)


def with_exact_duplicates(frame: Frame, share: float = 0.25, seed: int = 0) -> Frame:
    """``frame`` plus exact copies of ``share`` of its points, shuffled in (attributes follow):
    what nuScenes frames hold (34,752 points, 25,532 distinct) and Draco merges."""
    rng = np.random.default_rng(seed)
    n = len(frame)
    idx = np.concatenate([np.arange(n), rng.integers(0, n, int(round(share * n)))])
    return frame.subset(idx[rng.permutation(len(idx))])


def hdl32_ring_scan(seed: int = 0, firings: int = 1086, marker: tuple[float, float, float] | None = None) -> Frame:
    """A 32-beam street scan (ground 1.8 m below, building fronts 8-25 m away in some
    directions, open sky elsewhere), ``firings`` x 32 points in firing order with a ring field,
    like a nuScenes ``LIDAR_TOP`` sweep.

    Each laser is up to 0.15 degrees off its nominal elevation. Rays that hit nothing are written
    as :data:`NO_RETURN`, so the upper rings, which mostly see the sky, are mostly that one point
    and their per-ring medians coincide: the sensor model derived from the ring field (as the
    loaders derive it) has several beams at one elevation. Both are what ordinary real scans do
    to codecs that assume clean data. ``marker`` writes them as another fixed point instead --
    older nuScenes files use one 0.19 m from the sensor (:data:`NUSCENES_NO_RETURN`), which a
    range test alone does not tell from a return.
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
    pts = unit_directions(az, el) * t[..., None]
    pts[~hit] = NO_RETURN if marker is None else marker
    points = pts.transpose(1, 0, 2).reshape(-1, 3).astype(np.float32)  # firing-major, as drivers write
    ring = np.tile(np.arange(32, dtype=np.uint16), firings)
    intensity = rng.uniform(0, 100, len(points)).astype(np.float32)
    sensor = SensorModel.from_points(points, ring=ring, rate_hz=20.0, name="derived")
    return Frame(points, sensor, index=0, intensity=intensity, ring=ring)


@functools.cache
def check_frames() -> dict[str, Frame]:
    """The scans every codec must handle, named: what a real sensor's scan has that the
    simulator's does not.

    - ``room``: a VLP-16 scan whose firings are off the range-image grid;
    - ``exact-duplicates``: every other return of it plus exact copies of a quarter of those;
    - ``hdl32-ring``: :func:`hdl32_ring_scan` (ring field, no-return filler points, a derived
      beam table with coincident beams).
    """
    room = room_scan(get_sensor("vlp16"), seed=1, dropout=0.02, index=3)
    half = room.subset(np.arange(0, len(room), 2))
    return {"room": room, "exact-duplicates": with_exact_duplicates(half, 0.25), "hdl32-ring": hdl32_ring_scan()}
