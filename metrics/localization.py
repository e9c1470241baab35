"""Localization after compression: map-based tracking (PocoNet §IV-B) and scan-to-scan odometry.

What a robot could still do with the decoded stream. Both trackers use Open3D's point-to-plane
ICP with one fixed parameter set (:data:`ICP_PARAMS`), stored with every result so that codecs
are only ever compared under identical settings.

- **Map tracking** (PocoNet): the decoded scans are placed at the ground-truth poses and merged
  into one map, voxel-filtered (the paper's octree grid filter: one centroid per voxel); map
  normals are estimated once. Each decoded scan is then registered against the map, starting
  from the previous frame's estimate; the first pose is given.
  One deliberate departure (``leave_one_out``, on by default): scan ``k`` is registered against
  the map of the *other* scans. With its own points in the map, a scan locks onto itself: any
  per-scan distortion a codec introduces is in the map too, and on simulated data (exact
  ground truth) raw and 5 % random scans both reach the same ~1 mm floor with the ordering
  flipping between seeds. PocoNet's real KITTI poses are a few cm off, which hides this there.
  ``leave_one_out=False`` gives the paper's exact protocol.
- **Odometry**: each decoded scan is registered against the previous decoded scan only (no map;
  the previous scan is filtered at the map's voxel size, which halved the drift on ring-pattern
  ground compared with the query's coarser voxel), initialised with the previous relative motion
  (constant velocity); the relative motions are chained from the given first pose: the drift a
  receiver of the compressed stream sees.

Neither estimate needs an alignment: both start at the ground-truth first pose in the world
frame. Trajectory errors are evo's APE/RPE (:mod:`lwbench_metrics.trajectory`) over the tracked
frames (the given first pose is left out of the APE statistics; RPE uses every consecutive pair).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from lwbench_metrics.trajectory import absolute_errors, error_statistics, relative_errors

from lwbench import import_open3d
from lwbench.geometry import transform, voxel_keys

if TYPE_CHECKING:
    import open3d as o3d

__all__ = [
    "ICP_PARAMS",
    "TrackingResult",
    "VoxelMap",
    "build_map",
    "track_against_map",
    "track_odometry",
    "pose_metrics",
]

# The fixed settings; changing one changes every codec's numbers, so it is stored per result.
ICP_PARAMS: dict[str, Any] = {
    "map_voxel": 0.2,  # m, the map's grid filter
    "leave_one_out": True,  # track each scan against the map of the *other* scans
    # m: a query scan keeps one measured point per 0.1 m voxel. PocoNet registers each compressed
    # scan as it is; a coarser query grid made every selector look alike -- at 0.5 m, raw and
    # random at 1/12 tracked within 8 % of each other on the two-drive street, at 0.1 m random is
    # 2x worse (tools/localization_protocol.py), as in PocoNet's Table I.
    "scan_voxel": 0.1,
    "normal_radius": 0.8,  # m, normals of the map / target scan
    "normal_max_nn": 20,
    # m, ICP correspondence gates, coarse to fine: 1 m reaches from the previous pose (1 m per
    # frame at 10 m/s), then 0.3 m drops the far matches that pulled single-gate estimates 1-2 cm
    # along the street (sim urban raw ATE 2.6-7.0 mm -> 1.2-1.3 mm over three seeds).
    "max_corr_dist": (1.0, 0.3),
    "max_iter": 30,
    "rel_fitness": 1e-6,
    "rel_rmse": 1e-6,
    "min_fitness": 0.3,  # below this share of matched query points a registration counts as failed
    "min_correspondences": 50,
}


@dataclass
class TrackingResult:
    """Estimated poses ``(n, 4, 4)`` and, per registration, whether it failed."""

    poses: np.ndarray
    failed: np.ndarray  # bool, one per tracked frame (frames 1..n-1)


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    o3d = import_open3d()
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def _with_normals(pc: o3d.geometry.PointCloud, p: dict[str, Any]) -> o3d.geometry.PointCloud:
    if len(pc.points) >= 3:
        pc.estimate_normals(import_open3d().geometry.KDTreeSearchParamHybrid(p["normal_radius"], p["normal_max_nn"]))
    return pc


@dataclass
class VoxelMap:
    """The decoded scans at their ground-truth poses, one centroid per voxel (the grid filter).

    Per-voxel sums and counts are kept per scan, so the map *without* one scan (leave-one-out,
    see :func:`track_against_map`) costs one subtraction instead of a rebuild. Normals are
    estimated once, on the full map.
    """

    sums: np.ndarray  # (M, 3) float64
    counts: np.ndarray  # (M,) int64
    normals: np.ndarray  # (M, 3)
    scan_voxels: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per scan: (map rows, sums, counts)

    def __len__(self) -> int:
        return len(self.counts)

    def cloud(self, without: int | None = None) -> o3d.geometry.PointCloud:
        """The map as an Open3D cloud with normals, optionally leaving scan ``without`` out."""
        sums, counts = self.sums, self.counts
        if without is not None and len(self.scan_voxels[without][0]):
            rows, s, c = self.scan_voxels[without]
            sums, counts = sums.copy(), counts.copy()
            sums[rows] -= s
            counts[rows] -= c
        keep = counts > 0
        pc = _cloud(sums[keep] / counts[keep, None])
        pc.normals = import_open3d().utility.Vector3dVector(self.normals[keep])
        return pc


def build_map(scans: list[np.ndarray], poses: np.ndarray, params: dict[str, Any] = ICP_PARAMS) -> VoxelMap:
    """Merge scans placed at ``poses`` into a voxel-centroid map with normals."""
    v = params["map_voxel"]
    keys, sums, counts, owner = [], [], [], []
    for i, (s, T) in enumerate(zip(scans, poses, strict=True)):
        if len(s) == 0:
            continue
        w = transform(s, T)
        k, inv, c = np.unique(voxel_keys(w, v), return_inverse=True, return_counts=True)
        keys.append(k)
        sums.append(np.stack([np.bincount(inv, weights=w[:, j], minlength=len(k)) for j in range(3)], axis=1))
        counts.append(c)
        owner.append(np.full(len(k), i))
    if not keys:
        empty = np.zeros((0, 3))
        none = (np.zeros(0, np.int64), empty, np.zeros(0, np.int64))
        return VoxelMap(empty, np.zeros(0, np.int64), empty, [none] * len(scans))
    uniq, rows = np.unique(np.concatenate(keys), return_inverse=True)
    sums_all, counts_all = np.concatenate(sums), np.concatenate(counts)
    total = np.stack(
        [np.bincount(rows, weights=sums_all[:, j], minlength=len(uniq)) for j in range(3)], axis=1
    )
    total_c = np.bincount(rows, weights=counts_all, minlength=len(uniq)).astype(np.int64)
    pc = _with_normals(_cloud(total / total_c[:, None]), params)
    normals = np.asarray(pc.normals) if pc.has_normals() else np.zeros((len(uniq), 3))
    owner_all = np.concatenate(owner)
    per_scan = []
    for i in range(len(scans)):
        sel = owner_all == i
        per_scan.append((rows[sel], sums_all[sel], counts_all[sel]))
    return VoxelMap(total, total_c, normals, per_scan)


def _query(points: np.ndarray, p: dict[str, Any]) -> o3d.geometry.PointCloud:
    """The query scan for ICP: fewer points for speed, each a *measured* point.

    One real point per ``scan_voxel`` voxel rather than the voxel's centroid: a centroid of a
    dense patch sits off the surface at edges and corners, which biased dense scans (on the
    simulated urban street: raw ATE 1.2-1.3 mm with centroids, 0.9-1.1 mm with real points).
    """
    pts = np.asarray(points, dtype=np.float64)
    _, first = np.unique(voxel_keys(pts, p["scan_voxel"]), return_index=True)
    return _cloud(pts[np.sort(first)])


def _register(
    source: np.ndarray, target: o3d.geometry.PointCloud, init: np.ndarray, p: dict[str, Any]
) -> tuple[np.ndarray, bool]:
    """Point-to-plane ICP of ``source`` (sensor frame) onto ``target``; returns (pose, failed).

    One ICP per correspondence gate, each starting where the previous one ended; a failure is
    judged on the last (tightest) stage.
    """
    src = _query(source, p)
    if len(src.points) < p["min_correspondences"] or len(target.points) < p["min_correspondences"]:
        return init, True
    reg = import_open3d().pipelines.registration
    gates = p["max_corr_dist"]
    pose = init
    for gate in gates if isinstance(gates, list | tuple) else (gates,):
        res = reg.registration_icp(
            src,
            target,
            gate,
            pose,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(p["rel_fitness"], p["rel_rmse"], p["max_iter"]),
        )
        pose = res.transformation
    failed = res.fitness < p["min_fitness"] or len(res.correspondence_set) < p["min_correspondences"]
    return np.asarray(res.transformation), bool(failed)


def track_against_map(
    scans: list[np.ndarray],
    first_pose: np.ndarray,
    world_map: VoxelMap,
    params: dict[str, Any] = ICP_PARAMS,
) -> TrackingResult:
    """PocoNet's pose tracking: each scan against the map, from the previous estimate.

    With ``params["leave_one_out"]`` each scan is registered against the map built from the
    *other* scans only (see the module notes for why).
    """
    poses = np.tile(np.asarray(first_pose, dtype=np.float64), (len(scans), 1, 1))
    failed = np.zeros(max(len(scans) - 1, 0), dtype=bool)
    full = None if params["leave_one_out"] else world_map.cloud()
    for k in range(1, len(scans)):
        target = full if full is not None else world_map.cloud(without=k)
        poses[k], failed[k - 1] = _register(scans[k], target, poses[k - 1], params)
    return TrackingResult(poses, failed)


def track_odometry(
    scans: list[np.ndarray], first_pose: np.ndarray, params: dict[str, Any] = ICP_PARAMS
) -> TrackingResult:
    """Scan-to-scan ICP chained from the first pose, with a constant-velocity initial guess."""
    poses = np.tile(np.asarray(first_pose, dtype=np.float64), (len(scans), 1, 1))
    failed = np.zeros(max(len(scans) - 1, 0), dtype=bool)
    motion = np.eye(4)
    target = None
    for k in range(len(scans)):
        prev_target = target
        target = (
            _with_normals(_cloud(scans[k]).voxel_down_sample(params["map_voxel"]), params)
            if len(scans[k])
            else _cloud(scans[k])
        )
        if k == 0:
            continue
        motion, failed[k - 1] = _register(scans[k], prev_target, motion, params)
        poses[k] = poses[k - 1] @ motion
    return TrackingResult(poses, failed)


def pose_metrics(ref: np.ndarray, result: TrackingResult, prefix: str = "") -> dict[str, float | None]:
    """ATE (rmse/mean, m), rotation error (mean, deg), mAPE, RPE (rmse, delta 1) and failures."""
    keys = ("ate_rmse", "ate_mean", "rot_err_deg", "mape", "rpe_trans", "rpe_rot_deg", "icp_failures")
    if len(ref) < 2:
        return {prefix + k: None for k in keys}
    est = result.poses
    ate = error_statistics(absolute_errors(ref[1:], est[1:], "translation_part"))
    rot = error_statistics(absolute_errors(ref[1:], est[1:], "rotation_angle_deg"))
    full = error_statistics(absolute_errors(ref[1:], est[1:], "full_transformation"))
    rpe_t = error_statistics(relative_errors(ref, est, "translation_part"))
    rpe_r = error_statistics(relative_errors(ref, est, "rotation_angle_deg"))
    values = {
        "ate_rmse": ate["rmse"],
        "ate_mean": ate["mean"],
        "rot_err_deg": rot["mean"],
        "mape": full["mean"],
        "rpe_trans": rpe_t["rmse"],
        "rpe_rot_deg": rpe_r["rmse"],
        "icp_failures": float(result.failed.sum()),
    }
    return {prefix + k: v for k, v in values.items()}
