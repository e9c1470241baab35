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

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from lwbench_metrics.trajectory import absolute_errors, error_statistics, relative_errors
from lwbench_metrics.voxel_map import (
    MapBuilder,
    VoxelMap,
    point_cloud,
    reach_columns,
    scan_voxels,
    with_normals,
)

from lwbench import import_open3d
from lwbench.geometry import transform, voxel_keys

if TYPE_CHECKING:
    import open3d as o3d

__all__ = [
    "ICP_PARAMS",
    "MapBuilder",
    "TrackingResult",
    "VoxelMap",
    "build_map",
    "scan_voxels",
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
    redone: int = 0  # registrations the cropped target could not vouch for, redone on the ball


def build_map(scans: Iterable[np.ndarray], poses: np.ndarray, params: dict[str, Any] = ICP_PARAMS) -> VoxelMap:
    """Merge scans placed at ``poses`` into a voxel-centroid map with normals (one pass over
    ``scans``, which may be a generator: none of them is kept)."""
    builder = MapBuilder(params["map_voxel"])
    for s, T in zip(scans, poses, strict=True):
        builder.add(s, T)
    return builder.finish(params)


def _query(points: np.ndarray, p: dict[str, Any]) -> o3d.geometry.PointCloud:
    """The query scan for ICP: fewer points for speed, each a *measured* point.

    One real point per ``scan_voxel`` voxel rather than the voxel's centroid: a centroid of a
    dense patch sits off the surface at edges and corners, which biased dense scans (on the
    simulated urban street: raw ATE 1.2-1.3 mm with centroids, 0.9-1.1 mm with real points).
    """
    pts = np.asarray(points, dtype=np.float64)
    _, first = np.unique(voxel_keys(pts, p["scan_voxel"]), return_index=True)
    return point_cloud(pts[np.sort(first)])


def _register(
    source: np.ndarray | o3d.geometry.PointCloud, target: o3d.geometry.PointCloud, init: np.ndarray,
    p: dict[str, Any],
) -> tuple[np.ndarray, bool]:
    """Point-to-plane ICP of ``source`` (sensor frame: a scan, or its :func:`_query` cloud) onto
    ``target``; returns (pose, failed).

    One ICP per correspondence gate, each starting where the previous one ended; a failure is
    judged on the last (tightest) stage.
    """
    src = source if not isinstance(source, np.ndarray) else _query(source, p)
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
    # A copy: Open3D's ``res.transformation`` is a view whose base is the whole RegistrationResult,
    # correspondence set included (~0.4 MB on a town scan). Kept as a tracked pose, each one held
    # its result alive: the tracking worker's memory grew ~0.45 MB a scan (docs/design.md).
    return np.array(res.transformation, dtype=np.float64), bool(failed)


def _widest_gate(p: dict[str, Any]) -> float:
    gates = p["max_corr_dist"]
    return float(max(gates)) if isinstance(gates, list | tuple) else float(gates)


def _reach(points: np.ndarray, p: dict[str, Any]) -> float:
    """How far from the sensor a registration of ``points`` can find a correspondence: the
    farthest point, plus the widest gate, plus room for the pose to move while ICP iterates."""
    gate = _widest_gate(p)
    far = float(np.sqrt(np.einsum("ij,ij->i", points, points).max())) if len(points) else 0.0
    return far + 2 * gate + 5.0


#: Room for the pose to move while ICP iterates from the previous estimate, when the tracking
#: target is cropped to what the scan can reach (:func:`reach_columns`): a point ``r`` metres out
#: may move ``TRANSLATION_ROOM_M + 2 sin(ROTATION_ROOM_DEG / 2) r``. The simulated town's route
#: moves 1 m and turns up to 5.6 degrees a scan (11 m at 119 m range); KITTI's cars ~1.5 m and a few
#: degrees. A registration that moved a point more than half its room is redone against the
#: whole ball (:func:`track_against_map`), so the room only decides how often that happens.
TRANSLATION_ROOM_M = 3.0
ROTATION_ROOM_DEG = 15.0


def _room(query: np.ndarray) -> np.ndarray:
    """How far each query point (sensor frame) may move during one registration (see above)."""
    ranges = np.sqrt(np.einsum("ij,ij->i", query, query))
    return TRANSLATION_ROOM_M + 2 * np.sin(np.radians(ROTATION_ROOM_DEG) / 2) * ranges


def track_against_map(
    scans: Iterable[np.ndarray],
    first_pose: np.ndarray,
    world_map: VoxelMap,
    params: dict[str, Any] = ICP_PARAMS,
    poses: np.ndarray | None = None,
) -> TrackingResult:
    """PocoNet's pose tracking: each scan against the map, from the previous estimate.

    One pass over ``scans`` (a generator is fine: one scan is held at a time). The target is the
    map within reach of the previous estimate (:func:`_reach`), cropped to the columns within a
    gate plus room of the query points (:func:`reach_columns`, :data:`TRANSLATION_ROOM_M`): on a
    long drive the ball holds every mapped street within ~130 m (1.2 M voxels on the town at
    1,500 scans) though the scan sees a part of it. When the registration moved a query point
    more than half its room, it is redone against the whole ball, so the crop never decides a
    pose. With ``params["leave_one_out"]`` each scan is registered against the map without its
    own points, which are recomputed from the scan at its ground-truth pose (``poses``, the poses
    the map was built at).
    """
    loo = params["leave_one_out"]
    if loo and poses is None:
        raise ValueError("leave_one_out tracking needs the ground-truth poses the map was built at")
    estimates: list[np.ndarray] = []
    failed: list[bool] = []
    redone = 0
    pose = np.asarray(first_pose, dtype=np.float64)
    for k, scan in enumerate(scans):
        if k > 0:
            own = scan_voxels(scan, poses[k], world_map.voxel) if loo else None
            ball = (pose[:3, 3], _reach(np.asarray(scan), params))
            query = _query(scan, params)
            q = np.asarray(query.points)
            room = _room(q)
            placed = transform(q, pose)
            columns = reach_columns(placed, room + _widest_gate(params))
            target = world_map.cloud(without=own, around=ball, columns=columns)
            found, bad = _register(query, target, pose, params)
            del target
            shift = transform(q, found) - placed
            moved = np.sqrt(np.einsum("ij,ij->i", shift, shift))
            if np.any(moved > room / 2):
                redone += 1
                found, bad = _register(query, world_map.cloud(without=own, around=ball), pose, params)
            pose = found
            failed.append(bad)
        estimates.append(pose)
    out = np.stack(estimates) if estimates else np.zeros((0, 4, 4))
    return TrackingResult(out, np.asarray(failed, dtype=bool), redone)


def track_odometry(
    scans: Iterable[np.ndarray], first_pose: np.ndarray, params: dict[str, Any] = ICP_PARAMS
) -> TrackingResult:
    """Scan-to-scan ICP chained from the first pose, with a constant-velocity initial guess
    (one pass: the previous scan is all it holds)."""
    estimates: list[np.ndarray] = []
    failed: list[bool] = []
    motion = np.eye(4)
    pose = np.asarray(first_pose, dtype=np.float64)
    target = None
    for k, scan in enumerate(scans):
        prev_target = target
        cloud = point_cloud(scan)
        target = with_normals(cloud.voxel_down_sample(params["map_voxel"]), params) if len(scan) else cloud
        if k > 0:
            motion, bad = _register(scan, prev_target, motion, params)
            failed.append(bad)
            pose = pose @ motion
        estimates.append(pose)
    out = np.stack(estimates) if estimates else np.zeros((0, 4, 4))
    return TrackingResult(out, np.asarray(failed, dtype=bool))


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
