"""Diagnostics for learned selectors: do their scores find the points the labels call useful,
and how precise would they have to be to beat random selection?

A *learned selector* keeps a budget of a scan's points by a per-point score (PocoNet: the
probability of "high priority"). A localization table alone cannot say why such a selector
wins or loses: its labels may be wrong, the network may not learn them, or the rule that turns
scores into a budget may waste them. These functions separate the three.

- **Truth labels** are per-point classes ``0`` low priority, ``1`` high priority, ``2`` ground,
  in the folder layout ``lwbench label`` writes (:class:`LabelFolder`): ``labels.json`` with each
  frame's point count, ``labels/NNNNNN.label`` one uint8 per point. Several *definitions* of the
  labels can be compared side by side (e.g. counts over every drive of a sequence -- non-causal
  for a drive that is tracked -- or counts from the mapping drive only, which a robot has).
- **Ranking quality**: :func:`roc_auc` of the scores (high against low, ground left out) and
  :func:`top_k_precision`; **what was kept**: :func:`kept_precision`, the share of truly high
  points among the kept non-ground points.
- **The noisy oracle** (:func:`noisy_classes`, :func:`noisy_oracle_curve`): the oracle's rule
  (:func:`select_by_class`: a ground quota, then high priority, then the rest) on labels whose
  high-priority set is corrupted to precision ``p`` -- the same number of points, a share ``p``
  truly high, the rest drawn at random from the truly low ones. ``p`` = the base rate is a
  random choice among non-ground points, ``p = 1`` the oracle. The localization error along the
  curve says what precision beats random selection, and a learned selector's own
  (:func:`kept_precision`, ATE) pair says where it sits. The errors of the curve are uniform at
  random; a network's are clustered, which can cost more or less than the curve says.
- :func:`balanced_order`: a ranking by score with spatial balance (round-robin over ground-plane
  cells, best score first in each), so that a smooth score does not spend the budget on one patch.

``lwbench diagnose`` (:mod:`.diagnose`) runs all of it on a dataset. This is PocoNet's research code:
it lives in the plugin, on the public API, not in lwbench's core.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lwbench import DataFormatError, Dataset, Frame, ParameterError, SequenceEvaluation, SequenceMetric

__all__ = [
    "LABEL_GROUND",
    "LABEL_HIGH",
    "LABEL_LOW",
    "LOW",
    "HIGH",
    "GROUND",
    "LabelFolder",
    "ScoreFolder",
    "write_score_folder",
    "roc_auc",
    "top_k_precision",
    "kept_precision",
    "noisy_classes",
    "select_by_class",
    "balanced_order",
    "select_by_score",
    "FrameDiagnostics",
    "frame_diagnostics",
    "summarize",
    "CurvePoint",
    "noisy_oracle_curve",
    "crossing",
]

LOW, HIGH, GROUND = 0, 1, 2
# The same class codes under the names the public API (``lwbench``) exports them by.
LABEL_LOW, LABEL_HIGH, LABEL_GROUND = LOW, HIGH, GROUND


class LabelFolder:
    """Per-point classes of a sequence's frames, in the layout ``lwbench label`` writes; each
    read is checked against the scan's point count (labels of another dataset are an error)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        path = self.root / "labels.json"
        if not path.is_file():
            raise DataFormatError(f"{self.root}: no labels.json (write labels with `lwbench label`)")
        try:
            self.meta: dict[str, Any] = json.loads(path.read_text())
            self._frames = {int(k): int(v) for k, v in self.meta["frames"].items()}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataFormatError(f"{path}: not a label index ({type(exc).__name__}: {exc})") from None

    def __contains__(self, index: int) -> bool:
        return index in self._frames

    def classes(self, index: int, n_points: int) -> np.ndarray:
        """``(n_points,)`` uint8 classes of frame ``index``."""
        expected = self._frames.get(index)
        if expected is None:
            raise DataFormatError(f"{self.root}: no labels for frame {index}")
        if expected != n_points:
            raise DataFormatError(
                f"{self.root}: labels of frame {index} are for {expected} points, "
                f"the scan has {n_points} (labels of another dataset?)"
            )
        path = self.root / "labels" / f"{index:06d}.label"
        lab = np.fromfile(path, dtype=np.uint8) if path.is_file() else np.empty(0, np.uint8)
        if len(lab) != n_points or lab.max(initial=0) > GROUND:
            raise DataFormatError(f"{self.root}: label file of frame {index} is damaged")
        return lab


SCORE_FORMAT = "lwbench-point-scores"


class ScoreFolder:
    """Per-point scores of a sequence's frames from outside the codec (``poconet score=file``):
    ``scores.json`` (format, the dataset's identity, each frame's point count, what wrote them)
    and ``scores/NNNNNN.f32``, one little-endian float32 per point. A selector can then rank by
    another model's scores under its own rule -- the control that says whether *better scores*
    would move the localization error. Each read is checked like :class:`LabelFolder`'s."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        path = self.root / "scores.json"
        if not path.is_file():
            raise DataFormatError(f"{self.root}: no scores.json (write scores with `lwbench poconet-ceiling "
                                  "--write-scores DIR`)")
        try:
            self.meta: dict[str, Any] = json.loads(path.read_text())
            if self.meta.get("format") != SCORE_FORMAT:
                raise KeyError("format")
            self._frames = {int(k): int(v) for k, v in self.meta["frames"].items()}
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            raise DataFormatError(f"{path}: not a score index ({type(exc).__name__}: {exc})") from None

    def scores(self, index: int, n_points: int) -> np.ndarray:
        """``(n_points,)`` float64 scores of frame ``index``."""
        expected = self._frames.get(index)
        if expected is None:
            raise DataFormatError(f"{self.root}: no scores for frame {index}")
        if expected != n_points:
            raise DataFormatError(f"{self.root}: scores of frame {index} are for {expected} points, the scan has "
                                  f"{n_points} (scores of another dataset?)")
        path = self.root / "scores" / f"{index:06d}.f32"
        got = np.fromfile(path, dtype="<f4") if path.is_file() else np.empty(0, "<f4")
        if len(got) != n_points or not np.isfinite(got).all():
            raise DataFormatError(f"{self.root}: score file of frame {index} is damaged")
        return got.astype(np.float64)


def write_score_folder(root: str | Path, dataset: Dataset, scores: dict[int, np.ndarray], source: str) -> Path:
    """Write ``scores`` (frame index -> per-point scores) in :class:`ScoreFolder`'s layout."""
    root = Path(root)
    (root / "scores").mkdir(parents=True, exist_ok=True)
    for i, s in scores.items():
        s = np.asarray(s, dtype="<f4")
        if not np.isfinite(s).all():
            raise ParameterError(f"scores of frame {i} are not all finite")
        s.tofile(root / "scores" / f"{i:06d}.f32")
    meta = {"format": SCORE_FORMAT, "dataset": dataset.identity(), "source": source,
            "frames": {str(i): int(len(s)) for i, s in scores.items()}}
    (root / "scores.json").write_text(json.dumps(meta, indent=1))
    return root


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve: the chance that a random positive outscores a random negative
    (ties count one half; Mann-Whitney U on average ranks). NaN without both kinds."""
    from scipy.stats import rankdata

    s = np.asarray(scores, dtype=np.float64)
    pos = np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(pos.sum()), int((~pos).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def top_k_precision(scores: np.ndarray, positive: np.ndarray, k: int) -> float:
    """Share of positives among the ``k`` best-scored points (ranking alone, no selection rule)."""
    k = int(min(k, len(scores)))
    if k <= 0:
        return float("nan")
    top = np.argpartition(-np.asarray(scores, dtype=np.float64), k - 1)[:k]
    return float(np.asarray(positive, dtype=bool)[top].mean())


def kept_precision(classes: np.ndarray, kept: np.ndarray) -> float:
    """Share of truly high-priority points among the kept points that are not truly ground: the
    precision a selection reached, comparable with the noisy oracle's ``p``."""
    c = np.asarray(classes)[np.asarray(kept, dtype=np.int64)]
    rest = c != GROUND
    return float((c[rest] == HIGH).mean()) if rest.any() else float("nan")


def noisy_classes(classes: np.ndarray, precision: float, rng: np.random.Generator) -> np.ndarray:
    """The labels with their high-priority set replaced by one of the same size and precision
    ``precision``: ``round(p * n_high)`` truly high points and the rest truly low ones, each drawn
    uniformly at random; ground stays as it is. Too few low points cap the false positives."""
    if not 0.0 <= precision <= 1.0:
        raise ParameterError(f"noisy oracle: precision {precision} is not in [0, 1]")
    c = np.asarray(classes)
    high, low = np.flatnonzero(c == HIGH), np.flatnonzero(c == LOW)
    n_true = int(round(precision * len(high)))
    n_false = min(len(high) - n_true, len(low))
    out = c.copy()
    out[high] = LOW
    out[rng.choice(high, n_true, replace=False)] = HIGH
    out[rng.choice(low, n_false, replace=False)] = HIGH
    return out


def select_by_class(classes: np.ndarray, k: int, seed: int, index: int, ground_share: float = 0.0) -> np.ndarray:
    """The oracle's budget rule: ``ground_share`` of the budget from ground ("most points marked
    as high priority and some ground points", PocoNet §III-A), then high priority, then ground,
    then the rest; a seeded random order within a class (a class's points are equal), so the
    kept points spread over the class instead of one patch of it."""
    cls = np.asarray(classes)
    k = int(min(k, len(cls)))
    order = np.random.default_rng([seed, index, 1]).permutation(len(cls))
    high, ground, rest = (order[cls[order] == c] for c in (HIGH, GROUND, LOW))
    reserved = min(len(ground), round(ground_share * k))
    n_high = min(len(high), k - reserved)
    n_ground = min(len(ground), k - n_high)
    keep = np.concatenate([high[:n_high], ground[:n_ground], rest[: k - n_high - n_ground]])
    return np.sort(keep).astype(np.int64)


def balanced_order(points: np.ndarray, scores: np.ndarray, cell: float, rng: np.random.Generator) -> np.ndarray:
    """All indices, best first, by score with spatial balance: the points are binned into
    ``cell`` x ``cell`` m cells of the x-y plane and taken round-robin -- every cell's best point,
    then every cell's second best, ... -- and within a round by score. Ties break at random.
    ``cell <= 0`` is the plain score order. Why: a network's score is smooth in space, and the
    top of a plain ranking is one patch (an early PocoNet checkpoint's 10,389 best points on a
    KITTI scan all lay in one 15 m sector), which ICP cannot register well."""
    s = np.asarray(scores, dtype=np.float64)
    n = len(s)
    shuffle = rng.permutation(n)
    if cell <= 0 or n == 0:
        return shuffle[np.argsort(-s[shuffle], kind="stable")]
    xy = np.floor(np.asarray(points, dtype=np.float64)[shuffle, :2] / cell).astype(np.int64)
    _, cell_id = np.unique(xy, axis=0, return_inverse=True)
    cell_id = cell_id.reshape(-1)
    by_cell = np.lexsort((-s[shuffle], cell_id))  # cell by cell, best first inside each
    starts = np.flatnonzero(np.r_[True, np.diff(cell_id[by_cell]) != 0])
    sizes = np.diff(np.r_[starts, n])
    rank = np.empty(n, np.int64)
    rank[by_cell] = np.arange(n) - np.repeat(starts, sizes)
    return shuffle[np.lexsort((-s[shuffle], rank))]


def select_by_score(
    points: np.ndarray,
    classes: np.ndarray,
    scores: np.ndarray,
    k: int,
    rng: np.random.Generator,
    ground_share: float = 0.1,
    cell: float = 3.0,
) -> np.ndarray:
    """A learned selector's budget rule: exactly ``k`` indices, ``ground_share`` of them from the
    points classed ground (at random: the ground's points are alike), the rest from the other
    points in the :func:`balanced_order` of ``scores``, topped up from ground if those run out."""
    cls = np.asarray(classes)
    k = int(min(k, len(cls)))
    ground = rng.permutation(np.flatnonzero(cls == GROUND))
    rest = np.flatnonzero(cls != GROUND)
    n_ground = min(len(ground), round(ground_share * k))
    n_rest = min(len(rest), k - n_ground)
    ranked = rest[balanced_order(np.asarray(points)[rest], np.asarray(scores)[rest], cell, rng)[:n_rest]]
    return np.sort(np.concatenate([ground[: k - n_rest], ranked])).astype(np.int64)


@dataclass
class FrameDiagnostics:
    """One frame's counts against one label definition (sums, so frames add up)."""

    high: int = 0  # truly high-priority points
    low: int = 0
    kept_high: int = 0  # kept points that are truly high / low / ground
    kept_low: int = 0
    kept_ground: int = 0
    top_k_hits: int = 0  # truly high among the (kept non-ground count) best-scored non-ground points
    top_k: int = 0
    auc: float = float("nan")  # this frame's ROC AUC (the summary averages over frames)

    def add(self, other: FrameDiagnostics) -> FrameDiagnostics:
        out = FrameDiagnostics(
            **{
                k: getattr(self, k) + getattr(other, k)
                for k in ("high", "low", "kept_high", "kept_low", "kept_ground", "top_k_hits", "top_k")
            }
        )
        return out


def frame_diagnostics(classes: np.ndarray, kept: np.ndarray, scores: np.ndarray | None) -> FrameDiagnostics:
    """A selection (``kept`` indices) and its scores (or ``None``) against one frame's classes."""
    c = np.asarray(classes)
    kc = c[np.asarray(kept, dtype=np.int64)]
    d = FrameDiagnostics(
        high=int((c == HIGH).sum()),
        low=int((c == LOW).sum()),
        kept_high=int((kc == HIGH).sum()),
        kept_low=int((kc == LOW).sum()),
        kept_ground=int((kc == GROUND).sum()),
    )
    if scores is not None:
        rest = c != GROUND
        s, pos = np.asarray(scores)[rest], c[rest] == HIGH
        d.top_k = d.kept_high + d.kept_low
        d.top_k_hits = int(round(top_k_precision(s, pos, d.top_k) * d.top_k)) if d.top_k else 0
        d.auc = roc_auc(s, pos)
    return d


def summarize(frames: Sequence[FrameDiagnostics]) -> dict[str, float]:
    """Base rate, mean per-frame AUC, top-k precision and kept precision over frames."""
    total = FrameDiagnostics()
    for f in frames:
        total = total.add(f)
    aucs = [f.auc for f in frames if np.isfinite(f.auc)]
    kept_rest = total.kept_high + total.kept_low
    kept_all = kept_rest + total.kept_ground
    return {
        "base_rate": total.high / max(1, total.high + total.low),
        "auc": float(np.mean(aucs)) if aucs else float("nan"),
        "top_k_precision": total.top_k_hits / total.top_k if total.top_k else float("nan"),
        "kept_precision": total.kept_high / kept_rest if kept_rest else float("nan"),
        "kept_ground_share": total.kept_ground / kept_all if kept_all else float("nan"),
    }


@dataclass
class CurvePoint:
    """One precision of the noisy-oracle curve and the localization metric's values there."""

    precision: float
    values: dict[str, float | None] = field(default_factory=dict)


def noisy_oracle_curve(
    dataset: Dataset,
    frame_indices: Sequence[int],
    classes_of: Callable[[Frame], np.ndarray],
    budget_of: Callable[[int], int],
    precisions: Sequence[float],
    metric: SequenceMetric,
    ground_share: float = 0.1,
    seed: int = 0,
    cache: dict | None = None,
    rule: str = "class",
    cell: float = 3.0,
) -> list[CurvePoint]:
    """The noisy oracle at each precision, scored by ``metric`` (the localization metric) over
    ``frame_indices``. ``classes_of(frame)`` gives the truth, ``budget_of(n_points)`` the budget;
    the corruption is seeded by ``(seed, frame, p)``. ``rule``: ``"class"`` is the oracle's
    :func:`select_by_class`; ``"score"`` is a learned selector's :func:`select_by_score` with the
    corrupted high-priority set as the score (1 or 0), so the curve is comparable with a selector
    that ranks with spatial balance -- its point at the base rate is that rule on random scores.
    ``cache`` is shared with other evaluations of the same frames (the originals' tracking)."""
    if rule not in ("class", "score"):
        raise ParameterError(f"noisy oracle: rule {rule!r} is not 'class' or 'score'")
    shared = {} if cache is None else cache
    frames = [dataset[i] for i in frame_indices]
    truth = [classes_of(f) for f in frames]
    out = []
    for p in precisions:
        decoded = []
        for f, c in zip(frames, truth, strict=True):
            rng = np.random.default_rng([seed, f.index, int(round(1e6 * p))])
            noisy = noisy_classes(c, p, rng)
            k = budget_of(len(f))
            if rule == "class":
                keep = select_by_class(noisy, k, seed, f.index, ground_share)
            else:
                keep = select_by_score(f.points, noisy, (noisy == HIGH).astype(np.float64), k, rng, ground_share, cell)
            decoded.append(np.asarray(f.points[keep], dtype=np.float32))
        seq = SequenceEvaluation(
            dataset, list(frame_indices), decoded, "noisy-oracle", {"precision": p, "rule": rule}, seed, _cache=shared
        )
        out.append(CurvePoint(float(p), metric.compute(seq)))
    return out


def crossing(curve: Sequence[tuple[float, float]], level: float) -> float | None:
    """The smallest precision from which a (precision, error) curve stays below ``level``,
    interpolated linearly between points; ``None`` if its last point is not below it."""
    pts = sorted(curve)
    if not pts or not pts[-1][1] < level:
        return None
    j = len(pts) - 1
    while j > 0 and pts[j - 1][1] < level:
        j -= 1
    if j == 0:
        return pts[0][0]
    (p0, e0), (p1, e1) = pts[j - 1], pts[j]
    return p0 + (p1 - p0) * (e0 - level) / (e0 - e1) if e0 != e1 else p1
