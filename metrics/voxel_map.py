"""The localization protocol's map, in bounded memory: scans placed at their poses, merged into one
voxel-centroid map with normals, its tiles spilled to disk when the route has left them.

The map's columns (``COLUMN_M`` squares in x, y) are how the tracker crops its target to what a
scan can reach (:func:`reach_columns`). Split out of :mod:`lwbench_metrics.localization`, which
tracks against this map, so that neither module passes 500 lines; the maths are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lwbench import SpillingTiles, import_open3d, split_by_tile, tiles_at, tiles_near
from lwbench.geometry import transform, voxel_keys

if TYPE_CHECKING:
    import open3d as o3d

__all__ = [
    "COLUMN_M",
    "MapBuilder",
    "VoxelMap",
    "column_tiles",
    "in_columns",
    "point_cloud",
    "reach_columns",
    "scan_voxels",
    "with_normals",
]

#: Side of the crop's columns, metres: coarse enough that dilating them is cheap (a few thousand
#: columns a scan), fine enough that the crop is mostly what the scan sees.
COLUMN_M = 4.0


def point_cloud(points: np.ndarray) -> o3d.geometry.PointCloud:
    o3d = import_open3d()
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))


def with_normals(pc: o3d.geometry.PointCloud, p: dict[str, Any]) -> o3d.geometry.PointCloud:
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
            cloud = with_normals(point_cloud(np.concatenate(halo)), params)
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
            touched = set(column_tiles(columns, self.voxel).tolist())
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
                rows = rows[in_columns(item.centroids()[rows], columns)]
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
        pc = point_cloud(np.concatenate(points) if points else np.zeros((0, 3)))
        pc.normals = import_open3d().utility.Vector3dVector(np.concatenate(normals) if normals else np.zeros((0, 3)))
        return pc

    def close(self) -> None:
        self.tiles.close()


def _column_index(xy: np.ndarray) -> np.ndarray:
    return np.floor(np.asarray(xy)[:, :2] / COLUMN_M).astype(np.int64)


def _column_id(ij: np.ndarray) -> np.ndarray:
    return (ij[:, 0] << 32) + (ij[:, 1] & 0xFFFFFFFF)


def _column_ij(ids: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_column_id`: ``(i, j)`` rows."""
    j = ids & 0xFFFFFFFF
    return np.stack([ids >> 32, np.where(j >= 1 << 31, j - (1 << 32), j)], axis=1)


def in_columns(points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Whether each point's (x, y) lies in one of the sorted column ids."""
    if len(points) == 0 or len(columns) == 0:
        return np.zeros(len(points), dtype=bool)
    ids = _column_id(_column_index(points))
    at = np.minimum(np.searchsorted(columns, ids), len(columns) - 1)
    return columns[at] == ids


def column_tiles(columns: np.ndarray, voxel: float) -> np.ndarray:
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
