"""Geometry that codecs, metrics and datasets share, written once.

- **Voxel keys**: one ``int64`` per point naming its voxel, so grouping, de-duplication and map
  merging are a sort. Two flavours: *world* keys (``anchor="world"``) mean the same voxel in
  every scan -- what maps built from many scans need; 21 bits per axis, so up to 2**20 voxels
  either side of the origin (210 km at 0.2 m). *Scan* keys (``anchor="scan"``) are relative to
  the cloud's own bounding box, mixed-radix over its extent, so any extent works; they group
  and order voxels exactly like world keys (x, then y, then z) but mean nothing across clouds.
- **Angles**: the sensor-frame convention every part uses -- azimuth ``atan2(y, x)`` in
  ``[-pi, pi]``, elevation ``asin(z / r)`` (0 at the horizon, positive up).
- **Rigid transforms**: applying a 4x4 pose to points, and the 6-number (translation, rotation
  vector) form payloads carry.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "VOXEL_KEY_BITS",
    "cartesian",
    "pose_to_vec",
    "rotate",
    "spherical",
    "transform",
    "unit_directions",
    "vec_to_pose",
    "voxel_centres",
    "voxel_indices",
    "voxel_key_range_x",
    "voxel_keys",
]

VOXEL_KEY_BITS = 21
_OFFSET = 1 << (VOXEL_KEY_BITS - 1)
_MASK = (1 << VOXEL_KEY_BITS) - 1


# -- voxel keys ------------------------------------------------------------------------------
def voxel_keys(points: np.ndarray, size: float, *, anchor: str = "world") -> np.ndarray:
    """The voxel of each point as one sortable ``int64`` (x major, then y, then z).

    ``anchor="world"``: voxel ``floor(p / size)``, packed 21 bits per axis; raises ``ValueError``
    beyond +-2**20 voxels from the origin. ``anchor="scan"``: relative to the cloud's minimum
    corner; a grid too fine for one int64 falls back to ranking the voxels (same grouping and
    order, keys then not decodable).
    """
    if anchor == "world":
        idx = np.floor(np.asarray(points, dtype=np.float64) / size).astype(np.int64) + _OFFSET
        if len(idx) and (idx.min() < 0 or idx.max() > _MASK):
            raise ValueError(f"points beyond the +-{_OFFSET * size:.0f} m range of a {size} m voxel grid")
        return (idx[:, 0] << (2 * VOXEL_KEY_BITS)) | (idx[:, 1] << VOXEL_KEY_BITS) | idx[:, 2]
    if anchor != "scan":
        raise ValueError(f"anchor must be 'world' or 'scan', got {anchor!r}")
    pts = np.asarray(points)
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    # Coordinate-major float arithmetic: 1.7x faster than row-major integer columns on a
    # 124,668-point KITTI frame (measured for the keypoint detectors' voxel thinning).
    f = np.empty((3, len(pts)), dtype=np.float64)
    f[:] = pts.T
    f /= size
    np.floor(f, out=f)
    f -= f.min(axis=1, keepdims=True)  # whole numbers: exact in float64 below 2**53
    ijk = f.astype(np.int64)
    dims = ijk.max(axis=1) + 1
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0**62:
        _, rank = np.unique(ijk.T, axis=0, return_inverse=True)
        return rank.reshape(-1).astype(np.int64)
    return (ijk[0] * dims[1] + ijk[1]) * dims[2] + ijk[2]


def voxel_indices(keys: np.ndarray) -> np.ndarray:
    """Integer voxel indices ``(N, 3)`` of world voxel keys: ``floor(p / size)`` of the points
    :func:`voxel_keys` was given (the inverse of its packing)."""
    k = np.asarray(keys, dtype=np.int64)
    idx = np.stack([(k >> (2 * VOXEL_KEY_BITS)) & _MASK, (k >> VOXEL_KEY_BITS) & _MASK, k & _MASK], axis=1)
    return idx - _OFFSET


def voxel_centres(keys: np.ndarray, size: float) -> np.ndarray:
    """Centres ``(N, 3)`` of world voxel keys (the inverse of ``voxel_keys(anchor="world")``)."""
    k = np.asarray(keys, dtype=np.int64)
    idx = np.stack([(k >> (2 * VOXEL_KEY_BITS)) & _MASK, (k >> VOXEL_KEY_BITS) & _MASK, k & _MASK], axis=1)
    return (idx - _OFFSET + 0.5) * size


def voxel_key_range_x(x_lo: float, x_hi: float, size: float) -> tuple[int, int]:
    """``[lo, hi)`` of the world keys whose voxel's x index lies between those of ``x_lo`` and
    ``x_hi``: x is the major field, so such voxels are one contiguous run of sorted keys."""
    i0 = int(np.floor(x_lo / size)) + _OFFSET
    i1 = int(np.floor(x_hi / size)) + _OFFSET
    return max(i0, 0) << (2 * VOXEL_KEY_BITS), (min(i1, _MASK) + 1) << (2 * VOXEL_KEY_BITS)


# -- angles ----------------------------------------------------------------------------------
def spherical(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range, azimuth and elevation (float64) of sensor-frame points; 0 elevation at r = 0."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    r = np.linalg.norm(p, axis=1)
    az = np.arctan2(p[:, 1], p[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0))
    return r, az, el


def unit_directions(azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Unit vectors ``(..., 3)`` for broadcastable azimuth and elevation arrays (radians)."""
    az, el = np.broadcast_arrays(np.asarray(azimuth, dtype=np.float64), np.asarray(elevation, dtype=np.float64))
    ce = np.cos(el)
    return np.stack([ce * np.cos(az), ce * np.sin(az), np.sin(el)], axis=-1)


def cartesian(r: np.ndarray, azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Points ``(..., 3)`` from range, azimuth and elevation (the inverse of :func:`spherical`)."""
    return unit_directions(azimuth, elevation) * np.asarray(r, dtype=np.float64)[..., None]


# -- rigid transforms ------------------------------------------------------------------------
def rotate(points: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """``points @ rotation.T``, computed as ``(rotation @ points.T).T``: ~20x faster in numpy
    for ``(N, 3)`` arrays (the (N,3)@(3,3) form misses the fast BLAS path)."""
    return (np.asarray(rotation) @ np.asarray(points).T).T


def transform(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points moved by a 4x4 rigid transform (float64, contiguous)."""
    pose = np.asarray(pose, dtype=np.float64)
    return np.ascontiguousarray(rotate(np.asarray(points, dtype=np.float64), pose[:3, :3]) + pose[:3, 3])


def pose_to_vec(pose: np.ndarray) -> np.ndarray:
    """4x4 rigid transform -> ``(tx, ty, tz, rx, ry, rz)`` with a rotation vector (axis x angle)."""
    from scipy.spatial.transform import Rotation

    pose = np.asarray(pose, dtype=np.float64)
    return np.concatenate([pose[:3, 3], Rotation.from_matrix(pose[:3, :3]).as_rotvec()])


def vec_to_pose(vec: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pose_to_vec`."""
    from scipy.spatial.transform import Rotation

    vec = np.asarray(vec, dtype=np.float64)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(vec[3:]).as_matrix()
    pose[:3, 3] = vec[:3]
    return pose
