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

from lwbench import SpillingTiles, import_open3d, split_by_tile, tiles_at, tiles_near
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


def _cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    o3d = import_open3d()
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def _with_normals(pc: o3d.geometry.PointCloud, p: dict[str, Any]) -> o3d.geometry.PointCloud:
    if len(pc.points) >= 3:
        pc.estimate_normals(import_open3d().geometry.KDTreeSearchParamHybrid(p["normal_radius"], p["normal_max_nn"]))
    return pc


def scan_voxels(scan: np.ndarray, pose: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One scan placed at ``pose``, per map voxel it touches: (sorted keys, coordinate sums, counts)."""
    if len(scan) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
    w = transform(scan, pose)
    k, inv, c = np.unique(voxel_keys(w, voxel), return_inverse=True, return_counts=True)
    sums = np.stack([np.bincount(inv, weights=w[:, j], minlength=len(k)) for j in range(3)], axis=1)
    return k, sums, c


class _MapTile:
    """One tile of the map: per voxel, the coordinate sums and counts (running, plus scans that
    wait to be folded in), and once the map is finished the normals."""

    def __init__(self, keys=None, sums=None, counts=None, normals=None, least: int = 1 << 14) -> None:
        self.keys = np.zeros(0, np.int64) if keys is None else keys
        self.sums = np.zeros((0, 3)) if sums is None else sums
        self.counts = np.zeros(0, np.int64) if counts is None else counts
        self.normals = normals
        self._pending: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._pending_n, self._least = 0, least

    def add(self, keys: np.ndarray, sums: np.ndarray, counts: np.ndarray) -> None:
        self._pending.append((keys, sums, counts))
        self._pending_n += len(keys)
        if self._pending_n >= max(len(self.keys), self._least):
            self.fold()

    def fold(self) -> None:
        """Fold the waiting scans in: the running sums first, then each scan in order, so every
        voxel's sum is added up in scan order -- bit for bit what one ``bincount`` over all scans
        gives (``0 + x == x``), however the drive was cut into folds and tiles."""
        if not self._pending:
            return
        parts = [(self.keys, self.sums, self.counts), *self._pending]
        uniq, rows = np.unique(np.concatenate([p[0] for p in parts]), return_inverse=True)
        sums_all = np.concatenate([p[1] for p in parts])
        self.sums = np.stack([np.bincount(rows, weights=sums_all[:, j], minlength=len(uniq)) for j in range(3)], axis=1)
        self.counts = np.bincount(rows, weights=np.concatenate([p[2] for p in parts]),
                                  minlength=len(uniq)).astype(np.int64)
        self.keys = uniq
        self._pending, self._pending_n = [], 0

    def centroids(self) -> np.ndarray:
        return self.sums / np.maximum(self.counts, 1)[:, None]

    def nbytes(self) -> int:
        held = self.keys.nbytes + self.sums.nbytes + self.counts.nbytes + 40 * self._pending_n
        return held + (0 if self.normals is None else self.normals.nbytes)

    def arrays(self) -> dict[str, np.ndarray]:
        self.fold()
        out = {"keys": self.keys, "sums": self.sums, "counts": self.counts}
        if self.normals is not None:
            out["normals"] = self.normals
        return out

    @classmethod
    def load(cls, arrays: dict[str, np.ndarray]) -> _MapTile:
        return cls(arrays["keys"], arrays["sums"], arrays["counts"], arrays.get("normals"))


class MapBuilder:
    """The voxel-centroid map, built one scan at a time, in tiles (:mod:`lwbench.tiles`): the
    tiles the route is near stay in memory, the others wait on disk, so memory does not grow
    with the drive."""

    def __init__(self, voxel: float, budget: int | None = None) -> None:
        self.voxel = voxel
        self.tiles: SpillingTiles[_MapTile] = SpillingTiles(_MapTile, _MapTile.load, budget, name="map")

    def add(self, scan: np.ndarray, pose: np.ndarray) -> None:
        k, sums, c = scan_voxels(scan, pose, self.voxel)
        for tile, (kk, ss, cc) in split_by_tile(k, self.voxel, sums, c):
            self.tiles.get(tile).add(kk, ss, cc)
        self.tiles.settle()

    def finish(self, params: dict[str, Any]) -> VoxelMap:
        """The map, with normals: each tile's estimated with its neighbours' voxels within the
        normal radius beside it -- the neighbourhoods a whole-map estimate would search."""
        radius = float(params["normal_radius"])
        n = 0
        for tile in self.tiles.tiles():
            here = self.tiles.get(tile, create=False)
            here.fold()
            n += len(here.keys)
            pts = here.centroids()
            if len(pts) == 0:
                here.normals = np.zeros((0, 3))
                continue
            lo, hi = pts.min(axis=0) - radius, pts.max(axis=0) + radius
            halo = [pts]
            for other in self.tiles.neighbours(tile):
                near = self.tiles.get(other, create=False)
                if near is None:
                    continue
                near.fold()
                c = near.centroids()
                inside = np.all((c >= lo) & (c <= hi), axis=1)
                halo.append(c[inside])
            here = self.tiles.get(tile, create=False)  # a neighbour's read may have written it out
            cloud = _with_normals(_cloud(np.concatenate(halo)), params)
            normals = np.asarray(cloud.normals) if cloud.has_normals() else np.zeros((len(pts), 3))
            here.normals = normals[: len(pts)]
            self.tiles.settle()
        return VoxelMap(self.tiles, self.voxel, n)


@dataclass
class VoxelMap:
    """Scans at their ground-truth poses, one centroid per voxel (the grid filter), with normals,
    in tiles (most of a long drive's map on disk).

    :meth:`cloud` gives ICP its target: the map around a pose (a ball that holds every point a
    correspondence gate can reach from there, so the registration is the one against the whole
    map), optionally without one scan's points (leave-one-out: that scan's voxel sums, recomputed
    from the scan, are subtracted). Normals are the whole map's. :meth:`close` removes the tiles
    written to disk."""

    tiles: SpillingTiles[_MapTile]
    voxel: float
    n_voxels: int

    def __len__(self) -> int:
        return self.n_voxels

    def cloud(self, without: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
              around: tuple[np.ndarray, float] | None = None,
              columns: np.ndarray | None = None) -> o3d.geometry.PointCloud:
        """The map as an Open3D cloud with normals: the voxels whose centroid is within ``around =
        (centre, radius)`` when given (every voxel when not) and, when ``columns`` (sorted ids
        from :func:`reach_columns`) is given, in one of those columns; less ``without =
        scan_voxels(...)`` of one scan when given. A tile no column touches is not read at all.

        Built tile by tile, each tile's selected centroids and normals appended once: on a long
        drive the target is every voxel within ~130 m of the pose (700 k on the town), and
        gathering whole tiles' keys, sums, counts and normals, sorting them and copying them for
        the subtraction first took ~300 bytes a voxel at once (a tracking worker swung by 200 MB
        every scan); this takes the 48 bytes of the points and normals Open3D is handed."""
        if around is None:
            chosen = self.tiles.tiles()
        else:
            centre, radius = np.asarray(around[0], dtype=np.float64), float(around[1])
            chosen = [t for t in tiles_near(centre, radius, self.voxel) if t in self.tiles]
        if columns is not None:
            touched = set(_column_tiles(columns, self.voxel).tolist())
            chosen = [t for t in chosen if t in touched]
        own = {}
        if without is not None and len(without[0]):
            own = {tile: rows for tile, rows in split_by_tile(without[0], self.voxel, without[1], without[2])}
        points, normals = [], []
        for tile in chosen:
            item = self.tiles.get(tile, create=False)
            rows = np.arange(len(item.keys))
            if around is not None:  # chosen by the whole map's centroid, as before any subtraction
                d = item.centroids() - centre
                rows = np.flatnonzero(np.einsum("ij,ij->i", d, d) <= radius * radius)
            if columns is not None:
                rows = rows[_in_columns(item.centroids()[rows], columns)]
            sums, counts = item.sums[rows], item.counts[rows]
            if tile in own and len(rows):
                k, sub_sums, sub_counts = own[tile]
                keys = item.keys[rows]
                at = np.searchsorted(keys, k)
                ok = (at < len(keys)) & (keys[np.minimum(at, len(keys) - 1)] == k)
                sums[at[ok]] -= sub_sums[ok]
                counts[at[ok]] -= sub_counts[ok]
            keep = counts > 0
            points.append(sums[keep] / counts[keep, None])
            normals.append(item.normals[rows][keep])
        self.tiles.settle()
        pc = _cloud(np.concatenate(points) if points else np.zeros((0, 3)))
        pc.normals = import_open3d().utility.Vector3dVector(np.concatenate(normals) if normals else np.zeros((0, 3)))
        return pc

    def close(self) -> None:
        self.tiles.close()


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
    return _cloud(pts[np.sort(first)])


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
#: Side of the crop's columns, metres: coarse enough that dilating them is cheap (a few thousand
#: columns a scan), fine enough that the crop is mostly what the scan sees.
COLUMN_M = 4.0


def _room(query: np.ndarray) -> np.ndarray:
    """How far each query point (sensor frame) may move during one registration (see above)."""
    ranges = np.sqrt(np.einsum("ij,ij->i", query, query))
    return TRANSLATION_ROOM_M + 2 * np.sin(np.radians(ROTATION_ROOM_DEG) / 2) * ranges


def _column_index(xy: np.ndarray) -> np.ndarray:
    return np.floor(np.asarray(xy)[:, :2] / COLUMN_M).astype(np.int64)


def _column_id(ij: np.ndarray) -> np.ndarray:
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)


def _column_ij(ids: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_column_id`: ``(i, j)`` rows."""
    j = ids & 0xFFFFFFFF
    return np.stack([ids >> 32, np.where(j >= 1 << 31, j - (1 << 32), j)], axis=1)


def _in_columns(points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Whether each point's (x, y) lies in one of the sorted column ids."""
    if len(points) == 0 or len(columns) == 0:
        return np.zeros(len(points), dtype=bool)
    ids = _column_id(_column_index(points))
    at = np.minimum(np.searchsorted(columns, ids), len(columns) - 1)
    return columns[at] == ids


def _column_tiles(columns: np.ndarray, voxel: float) -> np.ndarray:
    """The map tiles the columns overlap (each column's four corners, a millimetre inside)."""
    ij = _column_ij(columns)
    lo = ij * COLUMN_M + 1e-3
    hi = (ij + 1) * COLUMN_M - 1e-3
    corners = np.concatenate([lo, hi, np.stack([lo[:, 0], hi[:, 1]], 1), np.stack([hi[:, 0], lo[:, 1]], 1)])
    return np.unique(tiles_at(corners, voxel))


def reach_columns(points_world: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Sorted ids of the ``COLUMN_M`` columns holding every (x, y) within ``radii[i]`` of some
    ``points_world[i]``: a superset (whole columns, z ignored) of where a correspondence can be.

    Each point's column is dilated by its radius in whole columns; points are grouped by how
    many columns that is, so the dilation is one broadcast per group."""
    if len(points_world) == 0:
        return np.zeros(0, np.int64)
    cols = _column_index(points_world)
    radii = np.asarray(radii, dtype=np.float64)
    steps = np.floor(radii / COLUMN_M).astype(np.int64) + 1  # a column |o| away is (|o| - 1) columns off
    out = []
    for step in np.unique(steps):
        group = steps == step
        here = _column_ij(np.unique(_column_id(cols[group])))
        span = np.arange(-step, step + 1)
        off = np.stack(np.meshgrid(span, span, indexing="ij"), axis=-1).reshape(-1, 2)
        # a column whose nearest edge is farther than the group's widest radius from the centre
        # column (anywhere in it) is out
        gap = np.maximum(np.abs(off) - 1, 0) * COLUMN_M
        off = off[np.einsum("ij,ij->i", gap, gap) <= float(radii[group].max()) ** 2]
        out.append(np.unique(_column_id((here[:, None, :] + off[None]).reshape(-1, 2))))
    return np.unique(np.concatenate(out))


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
        target = (
            _with_normals(_cloud(scan).voxel_down_sample(params["map_voxel"]), params) if len(scan) else _cloud(scan)
        )
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
