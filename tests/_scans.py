"""Synthetic spinning-LiDAR scans in the point orders real files use, for the loader tests.

Real drivers differ in ways that matter to deriving a sensor model: the order points are
written in (ring by ring, or firing by firing with the lasers interleaved), returns that are
missing, laser origins offset from the axis (which makes each laser's elevation, seen from the
sensor origin, wobble with range), per-laser azimuth offsets, and a field of view cropped to a
camera's. Each is a parameter here, so a test states which property it relies on.
"""

from __future__ import annotations

import math

import numpy as np

from lwbench import Frame, SensorModel, get_sensor


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
    el = np.radians(
        np.asarray(s.elevations_deg)[:, None] + rng.normal(0, 1, (s.n_beams, s.n_azimuth)) * elevation_noise_deg
    )
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


def street_scan(
    sensor: SensorModel | str,
    *,
    seed: int = 0,
    height: float = 1.73,
    laser_height_m: float = 0.0,
    table_jitter_deg: float = 0.0,
    dropout: float = 0.0,
    azimuth_offsets_deg: np.ndarray | None = None,
) -> np.ndarray:
    """A street seen by a spinning LiDAR ``height`` m above the ground, ring-major, as float32
    ``(N, 3)``: ground, building fronts 6-30 m away in some directions, open sky elsewhere (no
    return). Real-sensor traits as parameters: ``laser_height_m`` puts the lasers' origins that far
    above the data's origin (each beam's apparent elevation then drifts with range, as on KITTI,
    where it is ~0.2 m), ``table_jitter_deg`` moves each beam off the nominal table (a unit's
    calibration), ``azimuth_offsets_deg`` gives per-beam azimuth offsets (Ouster, Hesai)."""
    s = get_sensor(sensor) if isinstance(sensor, str) else sensor
    rng = np.random.default_rng(seed)
    el = np.radians(np.asarray(s.elevations_deg) + rng.uniform(-1, 1, s.n_beams) * table_jitter_deg)[:, None]
    offsets = np.zeros(s.n_beams) if azimuth_offsets_deg is None else np.asarray(azimuth_offsets_deg)
    az = np.radians((np.arange(s.n_azimuth) + rng.uniform(0, 1)) * s.azimuth_step_deg + offsets[:, None]) - np.pi
    wall_r = 6 + 24 * (0.5 + 0.5 * np.sin(3 * az + seed))
    wall_top = np.where(np.sin(5 * az + 1.0) > -0.2, 12.0, 0.0) - height
    origin_z = laser_height_m - height  # the lasers' origin relative to the ground
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(el < 0, origin_z / np.sin(el), np.inf)
    t_wall = wall_r / np.cos(el)
    t_wall = np.where(origin_z + t_wall * np.sin(el) < wall_top, t_wall, np.inf)
    t = np.minimum(t_ground, t_wall)
    t = np.where(t <= s.max_range, t, np.inf) * (1 + rng.normal(0, 0.001, t.shape))
    hit = np.isfinite(t) & (rng.random(t.shape) >= dropout)
    pts = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)
    pts = pts * np.where(hit, t, 0.0)[..., None]
    pts[..., 2] += laser_height_m  # seen from the data's origin, below the lasers
    return pts[hit].astype(np.float32)


def rotating_2d_laser_scan(
    *,
    seed: int = 0,
    scan_step_deg: float = 0.25,
    turn_step_deg: float = 0.5,
    offset_m: float = 0.05,
    in_plane_offset_m: float = 0.0,
    turn_start_deg: float = 0.0,
    keep: float = 1.0,
    half_extent: tuple[float, float, float] = (6.0, 4.0, 2.0),
) -> np.ndarray:
    """A 2-D laser scanner (270 deg in its plane, ``scan_step_deg`` apart, a Hokuyo's) turned about
    the vertical axis half a turn in ``turn_step_deg`` steps from ``turn_start_deg``, its mirror
    ``offset_m`` off the axis across the plane and ``in_plane_offset_m`` along it -- how ETH's
    libpointmatcher datasets were recorded. In a box room with a few boxes in it (the same in every
    scan); ``keep`` thins each line at random, as the published clouds are thinned. No beam
    table: every elevation from -90 to +90 deg is a firing angle. Float32 ``(N, 3)``, shuffled."""
    rng = np.random.default_rng(seed)
    beta = np.radians(np.arange(-135.0, 135.0 + 1e-9, scan_step_deg))  # in-plane angle from up
    phi = np.radians(np.arange(turn_start_deg, turn_start_deg + 180.0, turn_step_deg))[:, None]  # turn of the plane
    d_plane = np.stack([np.sin(beta), np.cos(beta)], axis=-1)  # (horizontal along the plane, up)
    dirs = np.stack(
        np.broadcast_arrays(
            d_plane[None, :, 0] * np.cos(phi), d_plane[None, :, 0] * np.sin(phi), d_plane[None, :, 1] + 0 * phi
        ),
        axis=-1,
    ).reshape(-1, 3)
    along, across = in_plane_offset_m, offset_m
    centre = np.stack(np.broadcast_arrays(along * np.cos(phi) - across * np.sin(phi),
                                          along * np.sin(phi) + across * np.cos(phi), 0 * phi), axis=-1)
    centre = np.broadcast_to(centre, (len(phi), len(beta), 3)).reshape(-1, 3)
    half = np.asarray(half_extent)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(dirs) > 1e-12, (np.sign(dirs) * half - centre) / dirs, np.inf).min(axis=1)
        boxes = np.random.default_rng(99)  # furniture: one layout for every scan
        for _ in range(8):
            lo = boxes.uniform(-half, half)
            hi = np.minimum(lo + boxes.uniform(0.3, 1.5, 3), half)
            t1, t2 = (lo - centre) / dirs, (hi - centre) / dirs
            t_in = np.nanmax(np.minimum(t1, t2), axis=1)
            t_out = np.nanmin(np.maximum(t1, t2), axis=1)
            t = np.where((t_in <= t_out) & (t_in > 0.1) & (t_in < t), t_in, t)
    pts = centre + dirs * (t * (1 + rng.normal(0, 0.002, len(t))))[:, None]
    if keep < 1.0:
        pts = pts[rng.random(len(pts)) < keep]
    return pts[rng.permutation(len(pts))].astype(np.float32)


def shuffled(points: np.ndarray, seed: int = 0) -> np.ndarray:
    """The points in random order: no ring- or firing-major reading left."""
    return points[np.random.default_rng(seed).permutation(len(points))]


def voxel_downsampled(points: np.ndarray, size: float) -> np.ndarray:
    """Voxel-downsampled as public keyframe sets are (Open3D: one averaged point a voxel)."""
    from lwbench import import_open3d

    o3d = import_open3d()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    return np.asarray(cloud.voxel_down_sample(size).points, dtype=np.float32)


def tilted(points: np.ndarray, deg: float) -> np.ndarray:
    """The scan in a frame pitched by ``deg`` (as a deskewed scan in a levelled frame)."""
    a = np.radians(deg)
    rot = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return (points.astype(np.float64) @ rot.T).astype(np.float32)


def rotated(frame: Frame, angle: float) -> Frame:
    """The scan turned by ``angle`` about the sensor's axis (z); its sensor model, ring labels
    and intensities unchanged: the "rotate a scan by a fraction of a cell" check."""
    c, s = math.cos(angle), math.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    points = (frame.points.astype(np.float64) @ turn.T).astype(np.float32)
    return Frame(points, frame.sensor, index=frame.index, intensity=frame.intensity, ring=frame.ring)
