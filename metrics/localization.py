"""Localization after compression: map-based tracking (PocoNet §IV-B) and scan-to-scan odometry.

What a robot could still do with the decoded stream. Both trackers use Open3D's point-to-plane
ICP with one fixed parameter set (:data:`ICP_PARAMS`), stored with every result so that codecs
are only ever compared under identical settings.

- **Map tracking** (PocoNet): the decoded scans are placed at the ground-truth poses and merged
  into one map, voxel-filtered (the paper's octree grid filter: one centroid per voxel); map
  normals are estimated once. Each decoded scan is then registered against the map, starting
  from the previous frame's estimate; the first pose is given.
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
from typing import Any

import numpy as np
import open3d as o3d
from lwbench_metrics.trajectory import absolute_errors, error_statistics, relative_errors

__all__ = ["ICP_PARAMS", "TrackingResult", "build_map", "track_against_map", "track_odometry", "pose_metrics"]

_reg = o3d.pipelines.registration

# The fixed settings; changing one changes every codec's numbers, so it is stored per result.
ICP_PARAMS: dict[str, Any] = {
    "map_voxel": 0.2,  # m, the map's grid filter
    "scan_voxel": 0.5,  # m, query scans are voxel-filtered before ICP (speed)
    "normal_radius": 0.8,  # m, normals of the map / target scan
    "normal_max_nn": 20,
    "max_corr_dist": 1.0,  # m, ICP correspondence gate
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
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def _transform(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    return np.asarray(points, dtype=np.float64) @ pose[:3, :3].T + pose[:3, 3]


def _with_normals(pc: o3d.geometry.PointCloud, p: dict[str, Any]) -> o3d.geometry.PointCloud:
    if len(pc.points) >= 3:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(p["normal_radius"], p["normal_max_nn"]))
    return pc


def build_map(
    scans: list[np.ndarray], poses: np.ndarray, params: dict[str, Any] = ICP_PARAMS
) -> o3d.geometry.PointCloud:
    """Merge scans placed at ``poses`` into one voxel-filtered map with normals.

    Each scan is voxel-filtered before merging and the merged cloud once more, which gives the
    same one-point-per-voxel map as filtering everything at once without holding every raw
    point in memory (centroids differ slightly where a voxel is seen from several scans).
    """
    v = params["map_voxel"]
    parts = [
        np.asarray(_cloud(_transform(s, T)).voxel_down_sample(v).points)
        for s, T in zip(scans, poses, strict=True)
        if len(s)
    ]
    if not parts:
        return o3d.geometry.PointCloud()
    return _with_normals(_cloud(np.concatenate(parts)).voxel_down_sample(v), params)


def _register(
    source: np.ndarray, target: o3d.geometry.PointCloud, init: np.ndarray, p: dict[str, Any]
) -> tuple[np.ndarray, bool]:
    """Point-to-plane ICP of ``source`` (sensor frame) onto ``target``; returns (pose, failed)."""
    src = _cloud(source).voxel_down_sample(p["scan_voxel"]) if len(source) else _cloud(source)
    if len(src.points) < p["min_correspondences"] or len(target.points) < p["min_correspondences"]:
        return init, True
    res = _reg.registration_icp(
        src,
        target,
        p["max_corr_dist"],
        init,
        _reg.TransformationEstimationPointToPlane(),
        _reg.ICPConvergenceCriteria(p["rel_fitness"], p["rel_rmse"], p["max_iter"]),
    )
    failed = res.fitness < p["min_fitness"] or len(res.correspondence_set) < p["min_correspondences"]
    return np.asarray(res.transformation), bool(failed)


def track_against_map(
    scans: list[np.ndarray],
    first_pose: np.ndarray,
    world_map: o3d.geometry.PointCloud,
    params: dict[str, Any] = ICP_PARAMS,
) -> TrackingResult:
    """PocoNet's pose tracking: each scan against the map, from the previous estimate."""
    poses = np.tile(np.asarray(first_pose, dtype=np.float64), (len(scans), 1, 1))
    failed = np.zeros(max(len(scans) - 1, 0), dtype=bool)
    for k in range(1, len(scans)):
        poses[k], failed[k - 1] = _register(scans[k], world_map, poses[k - 1], params)
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
