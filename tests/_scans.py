"""Synthetic spinning-LiDAR scans in the point orders real files use, for the loader tests.

Real drivers differ in ways that matter to deriving a sensor model: the order points are
written in (ring by ring, or firing by firing with the lasers interleaved), returns that are
missing, laser origins offset from the axis (which makes each laser's elevation, seen from the
sensor origin, wobble with range), per-laser azimuth offsets, and a field of view cropped to a
camera's. Each is a parameter here, so a test states which property it relies on.
"""

from __future__ import annotations

import numpy as np

from lwbench import SensorModel, get_sensor


def spinning_scan(
    sensor: SensorModel | str,
    *,
    order: str = "ring",
    seed: int = 0,
    elevation_noise_deg: float = 0.0,
    dropout: float = 0.0,
    start_deg: float = 0.0,
    fov_deg: float = 360.0,
    laser_order: np.ndarray | None = None,
    azimuth_offsets_deg: np.ndarray | None = None,
    ranges: tuple[float, float] = (4.0, 40.0),
) -> np.ndarray:
    """One sweep as float32 ``(N, 3)``.

    ``order``: ``"ring"`` (each beam's full turn, then the next, lowest beam first) or
    ``"firing"`` (every beam at one azimuth, in ``laser_order``, then the next azimuth).
    ``elevation_noise_deg``: spread of each laser's elevation as seen from the sensor origin
    (KITTI's HDL-64E: ~0.5 deg interquartile range per laser, more than the 0.33 deg between
    beams, because the laser origins are offset from the axis).
    ``azimuth_offsets_deg``: per-beam azimuth offsets (Ouster, Hesai). ``fov_deg``: keep only
    points within half of it of the +x axis.
    """
    s = get_sensor(sensor) if isinstance(sensor, str) else sensor
    rng = np.random.default_rng(seed)
    el = np.radians(np.asarray(s.elevations_deg)[:, None] + rng.normal(0, 1, (s.n_beams, s.n_azimuth))
                    * elevation_noise_deg)
    az_deg = start_deg + np.arange(s.n_azimuth) * s.azimuth_step_deg
    offsets = np.zeros(s.n_beams) if azimuth_offsets_deg is None else np.asarray(azimuth_offsets_deg)
    az = np.radians(az_deg[None, :] + offsets[:, None])
    r = rng.uniform(*ranges, size=(s.n_beams, s.n_azimuth))
    dirs = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)
    pts = dirs * r[..., None]
    keep = rng.random((s.n_beams, s.n_azimuth)) >= dropout
    wrapped = (np.degrees(az) + 180.0) % 360.0 - 180.0
    keep &= np.abs(wrapped) <= fov_deg / 2
    if order == "ring":
        flat, mask = pts.reshape(-1, 3), keep.reshape(-1)
    elif order == "firing":
        lasers = np.arange(s.n_beams) if laser_order is None else np.asarray(laser_order)
        flat = pts[lasers].transpose(1, 0, 2).reshape(-1, 3)
        mask = keep[lasers].T.reshape(-1)
    else:
        raise ValueError(order)
    return flat[mask].astype(np.float32)


def interleaved(n: int) -> np.ndarray:
    """HDL-32E-style firing order: lowest, middle, second lowest, second middle, ..."""
    half = n // 2
    return np.ravel(np.column_stack([np.arange(half), np.arange(half, n)]))


def write_bin(path, points: np.ndarray, intensity: np.ndarray | None = None) -> None:
    """A KITTI velodyne ``.bin``: float32 x, y, z, intensity."""
    inten = np.zeros(len(points), np.float32) if intensity is None else intensity
    np.column_stack([points, inten]).astype("<f4").tofile(path)
