"""``voxel``: voxel-grid down-sampling that keeps one real scan point per occupied voxel.

The classic map-building filter (PCL's ``VoxelGrid``, Open3D's ``voxel_down_sample``) replaces
each voxel's points by their centroid. Here the voxel keeps the *scan point nearest to that
centroid* (or to the voxel's centre) instead, so it is a selection codec: the kept points are
real returns, go through the shared point serializer, and their bytes are counted exactly like
those of the keypoint selectors it competes with.

Vectorized: integer voxel keys are packed into one int64 per point, grouped with one sort, and
the per-voxel winner is found with a second (lexicographic) sort -- no Python loop over points.
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, Param, SelectionCodec, hookimpl

__all__ = ["VoxelSelector", "voxel_keys"]

_BITS = 21  # bits per axis in the packed key: 2**21 voxels per axis (200 km at 0.1 m)


def voxel_keys(points: np.ndarray, size: float) -> np.ndarray:
    """One int64 per point naming its voxel (``floor(p / size)`` per axis, packed)."""
    ijk = np.floor(np.asarray(points, dtype=np.float64) / size).astype(np.int64)
    ijk -= ijk.min(axis=0)
    if len(ijk) and int(ijk.max()) >= 1 << _BITS:
        raise ValueError(f"voxel: scan spans more than 2**{_BITS} voxels of {size} m per axis")
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]


class VoxelSelector(SelectionCodec):
    """Keeps at most one point per voxel of side ``voxel_size``: the one nearest the voxel's
    centroid (the spot a centroid filter would report) or its geometric centre."""

    name = "voxel"
    version = "1"
    description = "voxel grid: one real scan point per occupied voxel"
    params = (
        Param("voxel_size", "float", 0.2, "voxel side in metres", low=1e-3, high=100.0),
        Param("keep", "str", "centroid", "which point a voxel keeps: nearest its centroid or its centre",
              choices=("centroid", "center")),
    )

    def select(self, frame: Frame) -> np.ndarray:
        pts = frame.points.astype(np.float64)
        n = len(pts)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        size = self.config["voxel_size"]
        _, inverse, counts = np.unique(voxel_keys(pts, size), return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        if self.config["keep"] == "centroid":
            target = np.stack([np.bincount(inverse, weights=pts[:, k]) for k in range(3)], axis=1)
            target /= counts[:, None]
        else:
            target = (np.floor(pts / size) + 0.5) * size
            target = target[np.unique(inverse, return_index=True)[1]]
        dist = np.einsum("ij,ij->i", pts - target[inverse], pts - target[inverse])
        # Sort by (voxel, distance, index): the first point of each voxel wins, ties to the
        # lower index, so the choice is deterministic.
        order = np.lexsort((np.arange(n), dist, inverse))
        first = np.ones(n, dtype=bool)
        first[1:] = inverse[order[1:]] != inverse[order[:-1]]
        return np.sort(order[first])


@hookimpl
def lwbench_codecs() -> list[type[VoxelSelector]]:
    return [VoxelSelector]
