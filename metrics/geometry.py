"""Point-to-point and point-to-plane distortion: Chamfer, Hausdorff, D1/D2 PSNR (MPEG pc_error).

For each direction (P->Q: every original point to its nearest decoded point, and Q->P) the
nearest-neighbour distances come from SciPy's cKDTree (parallel queries). The original's tree
and normals are cached per frame, so they are built once however many codecs are compared.

- chamfer = (mean d(P->Q) + mean d(Q->P)) / 2; hausdorff = max over both directions;
- D1 PSNR = 10 log10(3 p^2 / MSE) per direction, symmetric value = the worse (lower) one,
  with p = the sensor's max range unless the ``peak`` parameter fixes it (published LiDAR
  results use a fixed peak so that figures compare across papers: e.g. 59.70 for KITTI in
  RENO's evaluation, 30,000 for 1 mm-quantized Ford -- ``--metric-param geometry.peak=59.70``);
- D2 PSNR: the same with each error projected on a normal, exactly as MPEG's pc_error does it
  (:mod:`.pc_error`: duplicate points merged, original -> decoded on the decoded point's normal
  derived from the original's, decoded -> original on the original's; the original's normals
  from Open3D, 12 nearest neighbours). D1 and D2 PSNR are computed on the clouds with duplicate
  points merged, as pc_error does; Chamfer and Hausdorff on every point. Lossless reconstruction
  gives +inf.

Version 2: D2 follows pc_error's normals (version 1 projected both directions on the original
point's own normal: 3 dB lower for codecs that drop points).
"""

from __future__ import annotations

import math

import numpy as np

from lwbench import HIGHER, LOWER, Evaluation, FrameMetric, MetricId, Param, import_open3d, thread_budget

from .pc_error import pc_errors, unique_points

NORMAL_NEIGHBOURS = 12


def _normals(points: np.ndarray) -> np.ndarray:
    o3d = import_open3d()

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(NORMAL_NEIGHBOURS))
    return np.asarray(pcd.normals)


def psnr(mse: float, peak: float) -> float:
    return math.inf if mse <= 0 else 10.0 * math.log10(3.0 * peak * peak / mse)


class GeometryMetric(FrameMetric):
    name = "geometry"
    version = "2"
    order = 30
    ids = (
        MetricId("chamfer", "m", LOWER, default=True, role="distortion"),
        MetricId("hausdorff", "m", LOWER),
        MetricId("d1_psnr", "dB", HIGHER, role="distortion"),  # behind --columns: chamfer says it
        MetricId("d2_psnr", "dB", HIGHER),
    )
    description = "Chamfer and Hausdorff distances (m); D1/D2 PSNR (dB) as MPEG pc_error, peak = max range"
    params = (
        Param("peak", "float", None, "PSNR peak (m, MPEG pc_error's -r); default: the sensor's max range", low=1e-9),
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        p = ev.frame.points
        q = np.asarray(ev.decoded, dtype=np.float32)
        if len(p) == 0 or len(q) == 0:
            return dict.fromkeys(self.ids)
        peak = self.config["peak"] or ev.frame.sensor.max_range
        from scipy.spatial import cKDTree  # here, not at import: `lwbench list` stays fast

        tree_p = ev.cached("original_kdtree", lambda: cKDTree(p))
        d_pq, _ = cKDTree(q).query(p, workers=thread_budget())
        d_qp, _ = tree_p.query(q, workers=thread_budget())
        # PSNRs as pc_error: on the clouds with duplicates merged, D2 with its normals.
        unique = ev.cached("original_unique", lambda: unique_points(p))
        tree_u = ev.cached("original_unique_kdtree", lambda: cKDTree(unique))
        normals = ev.cached("original_unique_normals", lambda: _normals(unique))
        e = pc_errors(unique, normals, q, tree_u)
        d1 = min(psnr(e.d1_ab, peak), psnr(e.d1_ba, peak))
        d2 = min(psnr(e.d2_ab, peak), psnr(e.d2_ba, peak))
        return {
            "chamfer": float((d_pq.mean() + d_qp.mean()) / 2),
            "hausdorff": float(max(d_pq.max(), d_qp.max())),
            "d1_psnr": d1,
            "d2_psnr": d2,
        }
