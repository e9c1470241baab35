"""Occupancy maps: which voxels a sequence of scans says are occupied (public: ``lwbench``).

The VSGP paper builds OctoMaps from reconstructed scans; this is the same idea as a flat
log-odds voxel map (no octree needed), built by the occupancy metric once from the original and
once from the decoded sequence, both placed in the world with the ground-truth poses, and live by
the base process of ``lwbench stream`` (:class:`OccupancyMap`). It is core, not part of the
metric plugin, because the link needs it too and core never imports a plugin.

Per scan, like OctoMap's ``insertPointCloud``: every voxel holding an endpoint gets one *hit*;
every voxel a ray passes through before its endpoint gets one *miss*, unless the same scan also
hit it (occupied wins within a scan). A voxel is occupied when ``hits·l_hit + misses·l_miss > 0``
(OctoMap's default probabilities 0.7 / 0.4; no clamping, so the order of scans does not matter).

Free space only matters for voxels that were hit at least once (a voxel never hit can never be
occupied), so instead of stepping along ~10^5 rays per scan this asks, for each candidate voxel,
whether the scan's ray in the voxel's range-image cell passes through it (an exact ray/box slab
test) and leaves it before its return. Cost per scan is linear in the candidate voxels within the
scan's reach, not in ray length, which makes 0.05 m maps affordable. It approximates exact ray
traversal in one respect: each voxel is tested against the one return whose range-image cell
holds the voxel's centre, so where a voxel spans several cells, the other cells' rays are not
consulted (fewer misses than OctoMap would count, for original and decoded scans alike).
Original and decoded maps are built by the same procedure, so identical clouds score exactly 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from lwbench.geometry import rotate, voxel_centres, voxel_key_range_x, voxel_keys
from lwbench.sensors.model import SensorModel

__all__ = [
    "OCCUPANCY_PARAMS",
    "OccupancyMap",
    "compare_occupancy",
    "occupancy_maps",
    "occupancy_scores",
    "occupancy_tiles",
    "occupied_voxels",
]

OCCUPANCY_PARAMS: dict[str, Any] = {
    "resolutions": (0.2, 0.05),  # m; the unsuffixed ids use the first
    # m, OctoMap's insertion "maxrange": returns beyond it add no hit, their rays clear free
    # space up to it. Bounds the work per scan (and 5 cm cells are meaningless at 60 m anyway).
    "max_range": 30.0,
    "l_hit": math.log(0.7 / 0.3),
    "l_miss": math.log(0.4 / 0.6),
}

@dataclass
class _ScanRays:
    """What one scan says about free space: per range-image cell, the world direction and range
    of the return kept there, plus the voxels the scan hit (occupied wins within a scan)."""

    origin: np.ndarray  # float32 (3,)
    rotation: np.ndarray  # sensor -> world, (3, 3)
    ray_dir: np.ndarray  # float32 (n_rays, 3), zero where the cell has no return
    ray_range: np.ndarray  # float32 (n_rays,)
    reach: float
    hit_keys: np.ndarray  # sorted unique world keys


def _hit_keys(scan: np.ndarray, pose: np.ndarray, voxel: float, max_range: float) -> np.ndarray:
    s = np.asarray(scan, dtype=np.float64)
    s = s[np.einsum("ij,ij->i", s, s) <= max_range * max_range]
    return np.unique(voxel_keys(rotate(s, pose[:3, :3]) + pose[:3, 3], voxel))


def _scan_rays(scan: np.ndarray, pose: np.ndarray, sensor: SensorModel, max_range: float,
               hit_keys: np.ndarray) -> _ScanRays | None:
    """The scan's ray table (None if it has no return on the sensor's grid)."""
    if len(scan) == 0:
        return None
    img = sensor.project(scan)
    flat_index = img.index.ravel()
    valid = flat_index >= 0
    if not valid.any():
        return None
    q = np.asarray(scan, dtype=np.float64)[flat_index[valid]]
    q_range = np.linalg.norm(q, axis=1)
    ray_dir = np.zeros((len(flat_index), 3), dtype=np.float32)
    ray_range = np.zeros(len(flat_index), dtype=np.float32)
    ray_dir[valid] = rotate(q / q_range[:, None], pose[:3, :3])
    ray_range[valid] = np.minimum(q_range, max_range)
    reach = min(float(q_range.max()), max_range)
    return _ScanRays(pose[:3, 3].astype(np.float32), pose[:3, :3], ray_dir, ray_range, reach, hit_keys)


def _misses(cand: np.ndarray, rays: _ScanRays, sensor: SensorModel, voxel: float) -> np.ndarray:
    """Indices into the sorted keys ``cand`` of the voxels this scan's rays pass through before
    their return (and that the scan did not also hit)."""
    # Candidates are sorted by x index first: slice those within the scan's reach in x.
    x0 = float(rays.origin[0])
    lo, hi = np.searchsorted(cand, voxel_key_range_x(x0 - rays.reach, x0 + rays.reach, voxel))
    if hi <= lo:
        return np.zeros(0, dtype=np.int64)
    # 0.1 mm resolution at 1 km: plenty for >= 1 cm voxels
    centres = voxel_centres(cand[lo:hi], voxel).astype(np.float32)
    half = np.float32(voxel / 2)
    rel = centres - rays.origin
    r2 = np.einsum("ij,ij->i", rel, rel)
    sel = np.flatnonzero(r2 < rays.reach * rays.reach)
    rel = rel[sel]
    rows, cols, _ = sensor.cells(rotate(rel, rays.rotation.T.astype(np.float32)))  # the centre's ray-grid cell
    cell = rows * sensor.n_azimuth + cols
    u = rays.ray_dir[cell]
    # Slab test: where the return's ray enters and leaves the (axis-aligned) voxel.
    u = np.where(np.abs(u) < 1e-9, np.float32(1e-9), u)
    t1, t2 = (rel - half) / u, (rel + half) / u
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    # Column by column: numpy's max(axis=1) over three columns is a slow strided reduction
    # (6.4 of 28.9 s of the occupancy metric on 30 town scans); the values are the same.
    t_in = np.maximum(np.maximum(near[:, 0], near[:, 1]), near[:, 2])
    t_out = np.minimum(np.minimum(far[:, 0], far[:, 1]), far[:, 2])
    passed = (t_in <= t_out) & (t_in > 0) & (t_out < rays.ray_range[cell])
    idx = lo + sel[passed]
    hk = rays.hit_keys
    if len(hk) == 0:
        return idx
    pos = np.minimum(np.searchsorted(hk, cand[idx]), len(hk) - 1)
    return idx[hk[pos] != cand[idx]]  # occupied wins within a scan


class _KeyCounts:
    """Sorted unique keys and how often each was added, one scan's keys at a time. Pending keys
    are folded in once there are as many as distinct keys already (at least ``least``), so memory
    stays within about twice the distinct keys -- the area, not the scans -- and each key is
    sorted O(log) times over a drive."""

    def __init__(self, least: int = 1 << 16) -> None:
        self.keys = np.zeros(0, dtype=np.int64)
        self.counts = np.zeros(0, dtype=np.int64)
        self._pending: list[np.ndarray] = []
        self._n, self._least = 0, least

    def add(self, keys: np.ndarray) -> None:
        if len(keys):
            self._pending.append(keys)
            self._n += len(keys)
            if self._n >= max(len(self.keys), self._least):
                self.fold()

    def fold(self) -> tuple[np.ndarray, np.ndarray]:
        if self._pending:
            keys, rows = np.unique(np.concatenate([self.keys, *self._pending]), return_inverse=True)
            weights = np.concatenate([self.counts, np.ones(self._n, dtype=np.int64)])
            self.keys = keys
            self.counts = np.bincount(rows, weights=weights, minlength=len(keys)).astype(np.int64)
            self._pending, self._n = [], 0
        return self.keys, self.counts


ScanPasses = Callable[[str], Iterable[tuple[np.ndarray, np.ndarray]]]


class _CandidateTile:
    """One tile's candidate voxels: how often each was hit (pass 1), then missed (pass 2)."""

    def __init__(self, keys: np.ndarray | None = None, hits: np.ndarray | None = None,
                 misses: np.ndarray | None = None) -> None:
        self.counts = _KeyCounts()
        if keys is not None:
            self.counts.keys, self.counts.counts = keys, hits
        self.misses = misses

    def nbytes(self) -> int:
        c = self.counts
        return c.keys.nbytes + c.counts.nbytes + 8 * c._n + (0 if self.misses is None else self.misses.nbytes)

    def arrays(self) -> dict[str, np.ndarray]:
        keys, hits = self.counts.fold()
        out = {"keys": keys, "hits": hits}
        if self.misses is not None:
            out["misses"] = self.misses
        return out

    @classmethod
    def load(cls, arrays: dict[str, np.ndarray]) -> _CandidateTile:
        return cls(arrays["keys"], arrays["hits"], arrays.get("misses"))


def occupancy_tiles(
    scans: ScanPasses,
    sensor: SensorModel,
    emit: Callable[[float, int, np.ndarray], None],
    resolutions: tuple[float, ...] = OCCUPANCY_PARAMS["resolutions"],
    l_hit: float = OCCUPANCY_PARAMS["l_hit"],
    l_miss: float = OCCUPANCY_PARAMS["l_miss"],
    max_range: float = OCCUPANCY_PARAMS["max_range"],
) -> None:
    """The log-odds map of a sequence read as a stream, given tile by tile: ``emit(voxel, tile,
    occupied keys)`` for every tile (:mod:`lwbench.tiles`) at every resolution.

    ``scans(what)`` is one pass over ``(scan, pose)`` pairs in order (a generator: none is
    kept). Two passes: the first counts each voxel's hits (every voxel ever hit is a candidate),
    the second counts, per scan, the candidates its rays pass through -- what one scan's rays
    say depends on no other scan. A scan reaches only the tiles within ``max_range`` of its
    origin; the others wait on disk (:class:`~lwbench.tiles.SpillingTiles`), so memory is a few
    tiles whatever the length of the drive. Exact: integer counts, the same as one map's.
    """
    from lwbench.tiles import SpillingTiles, split_by_tile, tiles_near

    maps = {v: SpillingTiles(_CandidateTile, _CandidateTile.load, name=f"occupancy-{v:g}") for v in resolutions}
    try:
        for scan, pose in scans("occupancy hits"):
            pose = np.asarray(pose, dtype=np.float64)
            for v, tiles in maps.items():
                for tile, (keys,) in split_by_tile(_hit_keys(scan, pose, v, max_range), v):
                    tiles.get(tile).counts.add(keys)
                tiles.settle()
        for scan, pose in scans("occupancy free space"):
            pose = np.asarray(pose, dtype=np.float64)
            rays = None
            for v, tiles in maps.items():
                hk = _hit_keys(scan, pose, v, max_range)
                rays = _scan_rays(scan, pose, sensor, max_range, hk) if rays is None else replace(rays, hit_keys=hk)
                if rays is None:
                    break
                for tile in tiles_near(rays.origin, rays.reach + v, v):
                    cand = tiles.get(tile, create=False)
                    if cand is None:
                        continue
                    keys, _ = cand.counts.fold()
                    if cand.misses is None:
                        cand.misses = np.zeros(len(keys), dtype=np.int64)
                    cand.misses[_misses(keys, rays, sensor, v)] += 1
                tiles.settle()
        for v, tiles in maps.items():
            for tile, cand in tiles.drain():
                keys, hits = cand.counts.fold()
                misses = cand.misses if cand.misses is not None else np.zeros(len(keys), dtype=np.int64)
                emit(v, tile, keys[hits * l_hit + misses * l_miss > 0])
    finally:
        for tiles in maps.values():
            tiles.close()


def occupancy_maps(
    scans: ScanPasses,
    sensor: SensorModel,
    resolutions: tuple[float, ...] = OCCUPANCY_PARAMS["resolutions"],
    l_hit: float = OCCUPANCY_PARAMS["l_hit"],
    l_miss: float = OCCUPANCY_PARAMS["l_miss"],
    max_range: float = OCCUPANCY_PARAMS["max_range"],
) -> dict[float, np.ndarray]:
    """:func:`occupancy_tiles` gathered into one sorted key array per resolution (the whole map
    in memory: for a drive that fits; a metric over a long drive compares tile by tile)."""
    parts: dict[float, list[np.ndarray]] = {v: [] for v in resolutions}
    occupancy_tiles(scans, sensor, lambda v, tile, keys: parts[v].append(keys), resolutions, l_hit, l_miss,
                    max_range)
    return {v: np.sort(np.concatenate(p)) if p else np.zeros(0, dtype=np.int64) for v, p in parts.items()}


def occupied_voxels(
    scans: list[np.ndarray],
    poses: np.ndarray,
    sensor: SensorModel,
    voxel: float,
    l_hit: float = OCCUPANCY_PARAMS["l_hit"],
    l_miss: float = OCCUPANCY_PARAMS["l_miss"],
    max_range: float = OCCUPANCY_PARAMS["max_range"],
) -> np.ndarray:
    """Sorted keys of the voxels the log-odds map says are occupied.

    ``scans`` are in the sensor frame, ``poses`` are sensor->world; ``sensor`` gives the ray
    grid on which each scan's returns are looked up. (:class:`OccupancyMap` builds the same map
    one scan at a time; :func:`occupancy_maps` reads a sequence as a stream.)
    """
    poses = np.asarray(poses, dtype=np.float64)
    if len(scans) != len(poses):
        raise ValueError(f"{len(scans)} scans for {len(poses)} poses")
    maps = occupancy_maps(lambda what: zip(scans, poses, strict=True), sensor, (voxel,), l_hit, l_miss, max_range)
    return maps[voxel]


class OccupancyMap:
    """The log-odds map of :func:`occupied_voxels`, built live, one scan at a time (what the
    base of ``lwbench stream`` keeps): after any inserts, :meth:`occupied` equals
    ``occupied_voxels`` over the scans inserted so far, in any order, exactly.

    Each (candidate voxel, scan) pair is tested once: a new scan against every candidate, the
    voxels it adds against every earlier scan. For that it keeps each scan's ray table
    (16 bytes per range-image cell: ~0.9 MB per VLP-16 scan), so memory grows with the stream;
    ``lwbench stream`` bounds its streams in frames.
    """

    def __init__(self, sensor: SensorModel, voxel: float = OCCUPANCY_PARAMS["resolutions"][0],
                 l_hit: float = OCCUPANCY_PARAMS["l_hit"], l_miss: float = OCCUPANCY_PARAMS["l_miss"],
                 max_range: float = OCCUPANCY_PARAMS["max_range"]) -> None:
        self.sensor, self.voxel = sensor, voxel
        self.l_hit, self.l_miss, self.max_range = l_hit, l_miss, max_range
        self.cand = np.zeros(0, dtype=np.int64)
        self.hits = np.zeros(0, dtype=np.int64)
        self.misses = np.zeros(0, dtype=np.int64)
        self._rays: list[_ScanRays] = []
        self.scans = 0

    def insert(self, scan: np.ndarray, pose: np.ndarray) -> None:
        pose = np.asarray(pose, dtype=np.float64)
        hk = _hit_keys(scan, pose, self.voxel, self.max_range)
        new = np.setdiff1d(hk, self.cand, assume_unique=True)
        if len(new):
            merged = np.union1d(self.cand, new)
            old_pos = np.searchsorted(merged, self.cand)
            hits, misses = np.zeros(len(merged), np.int64), np.zeros(len(merged), np.int64)
            hits[old_pos], misses[old_pos] = self.hits, self.misses
            self.cand, self.hits, self.misses = merged, hits, misses
            new_pos = np.searchsorted(merged, new)
            for old in self._rays:  # the new voxels against every earlier scan's rays
                self.misses[new_pos[_misses(new, old, self.sensor, self.voxel)]] += 1
        self.hits[np.searchsorted(self.cand, hk)] += 1
        rays = _scan_rays(scan, pose, self.sensor, self.max_range, hk)
        if rays is not None:
            self.misses[_misses(self.cand, rays, self.sensor, self.voxel)] += 1
            self._rays.append(rays)
        self.scans += 1

    def occupied(self) -> np.ndarray:
        """Sorted keys of the occupied voxels."""
        return self.cand[self.hits * self.l_hit + self.misses * self.l_miss > 0]


def compare_occupancy(original: np.ndarray, decoded: np.ndarray) -> dict[str, float | None]:
    """IoU, precision and recall of the decoded occupied set against the original one."""
    inter = len(np.intersect1d(original, decoded, assume_unique=True))
    return occupancy_scores(len(original), len(decoded), inter)


def occupancy_scores(n_original: int, n_decoded: int, common: int) -> dict[str, float | None]:
    """IoU, precision and recall from the sizes of the two occupied sets and of their
    intersection (what a tile-by-tile comparison adds up)."""
    union = n_original + n_decoded - common
    return {
        "iou": common / union if union else None,
        "precision": common / n_decoded if n_decoded else None,
        "recall": common / n_original if n_original else None,
    }
