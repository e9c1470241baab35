"""PocoNet's training labels (§III-B): observation counts, ground, the dynamic threshold.

1. **Map**: every scan of a sequence placed at its ground-truth pose and merged (one centroid per
   ``map_voxel`` voxel: the paper's raw map has millions of duplicates of each surface patch,
   which change nothing but the cost).
2. **Observation counts**: a map point is *observed* at a pose when some point of that pose's scan
   lies within ``d_th`` (0.1 m) of it, counted once per pose however many scan points are near
   -- the paper's rule that a map point "cannot be observed multiple times repeatedly at one
   pose". The scans are already aligned by their poses (the paper aligns them by ICP first).
3. Each scan point takes the count of its nearest map point.
4. **Ground**: the scan's dominant near-horizontal plane by a seeded RANSAC
   (:func:`ground_mask`); ground is labelled apart because its counts are high for little
   localization value (it only constrains height, roll and pitch).
5. **Dynamic threshold** (Algorithm 1, ``r_th`` = 1/12): the largest count threshold that keeps
   at least ``N * r_th`` non-ground points "greater than" it, so each scan keeps about the same
   share whatever the vehicle's speed. Algorithm 1 as printed has two slips this does not copy:
   it starts with ``N_greater = N``, so its loop never runs (nothing would be high priority),
   and it decrements ``c_th`` after the test, returning one below the threshold that reached
   ``N_th`` -- a whole extra count level, which on a 10-pose sequence turned 8 % into 23 % of a
   scan. Ties at the threshold still make the share a little above ``r_th``.

Two definitions of the counts (``LabelSettings.counts_from``), both reported by ``lwbench
diagnose`` and named in every table:

- ``"all"`` (the paper's): the map and the counts come from every scan of the sequence. On a
  two-drive sequence (a mapping drive, then a tracking drive on another day) the tracked drive's
  labels count its *own* observations: an upper bound, not something a robot has while it tracks.
- ``"mapping"``: the map and the counts come from the mapping drive only (the dataset's first
  traversal); every scan of either drive takes the count of its nearest map point, and 0 when no
  map point is within ``d_th`` (a parked car that was not there on the mapping day). What a robot
  that has driven the mapping drive could compute.

Labels: 0 = low priority, 1 = high priority, 2 = ground.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench import DataFormatError, Dataset, Frame, ParameterError
from lwbench.geometry import transform, voxel_keys

from .diagnostics import LABEL_GROUND as GROUND
from .diagnostics import LABEL_HIGH as HIGH
from .diagnostics import LABEL_LOW as LOW
from .diagnostics import LabelFolder

__all__ = [
    "LOW",
    "HIGH",
    "GROUND",
    "CLASSES",
    "COUNTS_FROM",
    "LabelSettings",
    "dynamic_threshold",
    "observation_counts",
    "ground_mask",
    "frame_labels",
    "label_dataset",
    "LabelStore",
]

CLASSES = ("low priority", "high priority", "ground")
COUNTS_FROM = ("all", "mapping")


@dataclass(frozen=True)
class LabelSettings:
    d_th: float = 0.1  # m: a map point is observed at a pose when a scan point is this close
    r_th: float = 1 / 12  # share of a scan's points that are high priority (at least)
    # m: the map's one-centroid-per-voxel grid, d_th itself: 2.3x faster than 0.05 m (22 vs 52 s
    # for a 40-scan drive) with 98 % of the labels the same.
    map_voxel: float = 0.1
    ground_threshold: float = 0.2  # m: RANSAC inlier distance of the ground plane
    ground_normal_z: float = 0.9  # the plane counts as ground if |n_z| is at least this
    seed: int = 0  # RANSAC's seed
    counts_from: str = "all"  # "all" scans of the sequence, or the "mapping" drive only (see the module notes)


def dynamic_threshold(counts: np.ndarray, r_th: float, n_total: int | None = None) -> int:
    """Algorithm 1: the count threshold ``c_th`` (high priority = ``count > c_th``).

    ``counts`` are the candidates' (non-ground points') counts; ``N_th = n_total * r_th`` with
    ``n_total`` the scan's point count (default: ``len(counts)``)."""
    c = np.asarray(counts, dtype=np.int64)
    n_th = (len(c) if n_total is None else n_total) * r_th
    if len(c) == 0:
        return 0
    c_th = int(c.max())
    while int((c > c_th).sum()) < n_th and c_th >= int(c.min()):
        c_th -= 1  # lower the threshold one count at a time until enough points are above it
    return c_th


def build_map(scans_world: list[np.ndarray], voxel: float) -> np.ndarray:
    """The merged map: one centroid per ``voxel`` voxel of all world-frame scan points."""
    pts = np.concatenate(scans_world)
    keys = voxel_keys(pts, voxel)
    uniq, inv = np.unique(keys, return_inverse=True)
    inv = inv.reshape(-1)
    counts = np.bincount(inv, minlength=len(uniq)).astype(np.float64)
    return np.stack([np.bincount(inv, weights=pts[:, j], minlength=len(uniq)) for j in range(3)], 1) / counts[:, None]


def observation_counts(scans_world: list[np.ndarray], map_points: np.ndarray, d_th: float) -> np.ndarray:
    """Per map point, at how many poses some scan point lay within ``d_th`` of it.

    One k-d tree of the map, queried with each scan's points for their map points within
    ``d_th`` (at most 16 each; a point whose 16th is still within ``d_th`` is asked again for
    all of them, so the counts are exact). Measured on a two-drive street of 60 HDL-64E scans:
    the same counts as querying each scan's tree with the map points in its bounding box, in
    10 s instead of 18 s (that query's cost grows with the map, this one with the scans)."""
    from scipy.spatial import cKDTree

    counts = np.zeros(len(map_points), dtype=np.int64)
    if not len(map_points):
        return counts
    tree = cKDTree(map_points)
    for s in scans_world:
        if not len(s):
            continue
        dist, idx = tree.query(s, k=min(16, len(map_points)), distance_upper_bound=d_th, workers=-1)
        dist, idx = dist.reshape(len(s), -1), idx.reshape(len(s), -1)
        seen = [idx[np.isfinite(dist)]]
        full = np.isfinite(dist[:, -1])
        if full.any():
            seen += [np.asarray(n, dtype=np.int64) for n in tree.query_ball_point(s[full], d_th, workers=-1)]
        counts[np.unique(np.concatenate(seen))] += 1  # once per pose, however many scan points are near
    return counts


def ground_mask(points: np.ndarray, settings: LabelSettings) -> np.ndarray:
    """The scan's dominant near-horizontal plane (RANSAC), as a boolean mask.

    A seeded NumPy RANSAC rather than Open3D's ``segment_plane``: that one runs its iterations
    on several threads and, with the same seed, gave other ground on 8 of 60 scans of one street
    (up to 1.3 % of a scan's labels) from run to run. Here 200 planes through three random points
    each, only near-horizontal ones (``|n_z| >= ground_normal_z``: a façade can hold more points
    than the road), scored on a random 8,192-point subset, the best one's inliers on the scan."""
    p = np.asarray(points, dtype=np.float64)
    mask = np.zeros(len(p), dtype=bool)
    if len(p) < 3:
        return mask
    rng = np.random.default_rng([settings.seed, len(p)])
    a, b, c = (p[rng.integers(len(p), size=200)] for _ in range(3))
    normal = np.cross(b - a, c - a)
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 1e-9
    normal, a = normal[ok] / norm[ok, None], a[ok]
    flat = np.abs(normal[:, 2]) >= settings.ground_normal_z
    if not flat.any():
        return mask
    normal, a = normal[flat], a[flat]
    offset = -np.einsum("ij,ij->i", normal, a)
    subset = p[rng.choice(len(p), min(len(p), 8192), replace=False)]
    score = (np.abs(subset @ normal.T + offset) < settings.ground_threshold).sum(axis=0)
    best = int(np.argmax(score))
    return np.abs(p @ normal[best] + offset[best]) < settings.ground_threshold


def frame_labels(point_counts: np.ndarray, ground: np.ndarray, r_th: float) -> np.ndarray:
    """Labels of one scan from its points' counts and its ground mask (Algorithm 1)."""
    labels = np.full(len(point_counts), LOW, dtype=np.uint8)
    labels[ground] = GROUND
    rest = ~ground
    c_th = dynamic_threshold(point_counts[rest], r_th, n_total=len(point_counts))
    labels[rest & (point_counts > c_th)] = HIGH
    return labels


def label_dataset(
    dataset: Dataset, frames: list[int] | None = None, settings: LabelSettings = LabelSettings()
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(labels, counts) of every frame (default: all) of a dataset with ground-truth poses."""
    from scipy.spatial import cKDTree

    if settings.counts_from not in COUNTS_FROM:
        raise ParameterError(f"labels: counts_from {settings.counts_from!r} is not one of {COUNTS_FROM}")
    idx = list(range(len(dataset))) if frames is None else list(frames)
    loaded: list[Frame] = [dataset[i] for i in idx]
    if any(f.pose is None for f in loaded):
        raise DataFormatError(f"{dataset.name}: observation-count labels need a ground-truth pose on every frame")
    world = [transform(f.points, f.pose) for f in loaded]
    mapping = set(dataset.traversals()[0]) if settings.counts_from == "mapping" else set(idx)
    mapped = [w for i, w in zip(idx, world, strict=True) if i in mapping]
    if not mapped:
        raise DataFormatError(f"{dataset.name}: none of the labelled frames is in the mapping drive")
    map_points = build_map(mapped, settings.map_voxel)
    map_counts = observation_counts(mapped, map_points, settings.d_th)
    tree = cKDTree(map_points)
    labels, counts = [], []
    for f, w in zip(loaded, world, strict=True):
        dist, nearest = tree.query(w, k=1, workers=-1)
        c = map_counts[nearest]
        if settings.counts_from == "mapping":
            c = np.where(dist <= settings.d_th, c, 0)  # on nothing the mapping drive saw
        labels.append(frame_labels(c, ground_mask(f.points, settings), settings.r_th))
        counts.append(c.astype(np.uint16))
    return labels, counts


class LabelStore:
    """Labels on disk: ``labels/NNNNNN.label`` (uint8 per point, 0 low / 1 high / 2 ground),
    ``counts/NNNNNN.npy`` (observation counts) and ``labels.json`` (the dataset's identity,
    each frame's point count and the settings), so a reader can check they belong to the scans."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._folder: LabelFolder | None = None

    def write(
        self,
        dataset: Dataset,
        frames: list[int],
        labels: list[np.ndarray],
        counts: list[np.ndarray],
        settings: LabelSettings,
    ) -> None:
        (self.root / "labels").mkdir(parents=True, exist_ok=True)
        (self.root / "counts").mkdir(exist_ok=True)
        for i, lab, cnt in zip(frames, labels, counts, strict=True):
            lab.astype(np.uint8).tofile(self.root / "labels" / f"{i:06d}.label")
            np.save(self.root / "counts" / f"{i:06d}.npy", cnt, allow_pickle=False)
        meta = {
            "dataset": dataset.identity(),
            "frames": {str(i): int(len(lab)) for i, lab in zip(frames, labels, strict=True)},
            "classes": list(CLASSES),
            "settings": settings.__dict__,
        }
        (self.root / "labels.json").write_text(json.dumps(meta, indent=1))
        self._folder = None

    def meta(self) -> dict:
        path = self.root / "labels.json"
        if not path.is_file():
            raise DataFormatError(f"{self.root}: no labels.json (write labels with `lwbench label`)")
        return json.loads(path.read_text())

    def read(self, index: int, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        """(labels, counts) of frame ``index``, checked against the scan's point count (the
        classes through :class:`.diagnostics.LabelFolder`, the same reader
        ``lwbench diagnose`` uses)."""
        if self._folder is None:
            self._folder = LabelFolder(self.root)
        lab = self._folder.classes(index, n_points)
        path = self.root / "counts" / f"{index:06d}.npy"
        cnt = np.load(path, allow_pickle=False) if path.is_file() else np.empty(0)
        if len(cnt) != n_points:
            raise DataFormatError(f"{self.root}: count file of frame {index} is damaged")
        return lab, cnt
