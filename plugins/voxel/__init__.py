"""``voxel``: voxel-grid down-sampling that keeps one real scan point per occupied voxel.

The classic map-building filter (PCL's ``VoxelGrid``, Open3D's ``voxel_down_sample``) replaces
each voxel's points by their centroid. Here the voxel keeps the *scan point nearest to that
centroid* (or to the voxel's centre) instead, so it is a selection codec: the kept points are
real returns, go through the shared point serializer, and their bytes are counted exactly like
those of the keypoint selectors it competes with.

Vectorized: voxel keys (one int64 per point, :func:`lwbench.geometry.voxel_keys`) are grouped
with one stable sort; centroids, distances and the per-voxel minimum are reductions over the sorted runs -- no
Python loop over points.
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, Param, SelectionCodec, hookimpl
from lwbench.geometry import voxel_keys

__all__ = ["VoxelSelector"]

class VoxelSelector(SelectionCodec):
    """Keeps at most one point per voxel of side ``voxel_size``: the one nearest the voxel's
    centroid (the spot a centroid filter would report) or its geometric centre."""

    name = "voxel"
    in_default_run = True
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
        keys = voxel_keys(pts, size, anchor="scan")
        # One stable sort groups the voxels (ties keep index order); everything after it is
        # per-group reductions over contiguous runs.
        order = np.argsort(keys, kind="stable")
        sk = keys[order]
        starts = np.flatnonzero(np.r_[True, sk[1:] != sk[:-1]])
        counts = np.diff(np.r_[starts, n])
        sp = pts[order]
        if self.config["keep"] == "centroid":
            target = np.add.reduceat(sp, starts, axis=0) / counts[:, None]
        else:
            target = (np.floor(sp[starts] / size) + 0.5) * size
        diff = sp - np.repeat(target, counts, axis=0)
        dist = np.einsum("ij,ij->i", diff, diff)
        # The winner of a voxel is its first point (lowest index, by the stable sort) at the
        # voxel's minimum distance: deterministic, exactly one per voxel.
        is_min = dist == np.repeat(np.minimum.reduceat(dist, starts), counts)
        group = np.repeat(np.arange(len(starts)), counts)
        cand = np.flatnonzero(is_min)
        first = np.r_[True, group[cand[1:]] != group[cand[:-1]]]
        return np.sort(order[cand[first]])


@hookimpl
def lwbench_codecs() -> list[type[VoxelSelector]]:
    return [VoxelSelector]
