"""What the three detectors share: input checks, the budget rule and the ranking."""

from __future__ import annotations

import abc

import numpy as np

from lwbench import BUDGET_PARAMS, Frame, LwbenchError, Param, SelectionCodec

__all__ = ["KeypointError", "KeypointSelector", "MIN_POINTS", "MAX_NN_PARAM", "top_k"]

#: Fewer points than this cannot define a neighbourhood, a scatter matrix or a local maximum.
MIN_POINTS = 10

#: Neighbourhood cap of the hybrid (radius + k-nearest) search; see ``_geometry``.
MAX_NN_PARAM = Param(
    "max_nn", "int", 16,
    "at most this many nearest neighbours inside the radius (hybrid search, as Open3D's "
    "KDTreeSearchParamHybrid); caps cost where the scan is dense", low=4, high=512,
)


class KeypointError(LwbenchError, ValueError):
    """A scan a keypoint detector cannot work on (empty or too small)."""


def top_k(tier: np.ndarray, score: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` best points: lowest ``tier`` first, then highest ``score``.

    Ties (and undefined scores, given as ``-inf``/NaN) are broken by index, so the result
    is deterministic. This is the *budget rule* of every detector: tier 0 is the detector's
    own keypoints (local maxima after non-maximum suppression that pass its tests), the next
    tiers top the selection up when suppression leaves fewer than ``k``; the result is always
    exactly ``k`` points.
    """
    n = len(score)
    k = int(min(k, n))
    if k <= 0:
        return np.empty(0, dtype=np.int64)
    s = np.where(np.isnan(score), -np.inf, score)
    best = np.flatnonzero(tier == 0)
    if len(best) >= k:  # the common case: choose among tier 0 only (cheaper than a full sort)
        order = np.lexsort((best, -s[best]))
        return np.sort(best[order[:k]])
    order = np.lexsort((np.arange(n), -s, tier))
    return np.sort(order[:k])


class KeypointSelector(SelectionCodec):
    """A budgeted keypoint detector: response per point, then :func:`top_k` of the ranking.

    Subclasses implement :meth:`rank`, returning ``(tier, score)`` per point. The detector's
    own threshold (PCL's ``threshold``/``min_contrast``) is replaced by the budget, which is
    how PocoNet's comparison keeps 8,000-10,000 points per scan for every method.
    """

    params: tuple[Param, ...] = BUDGET_PARAMS

    @abc.abstractmethod
    def rank(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(tier, score)`` per point: lower tier first, then higher score."""

    def select(self, frame: Frame) -> np.ndarray:
        n = len(frame)
        if n < MIN_POINTS:
            raise KeypointError(
                f"{self.name}: frame {frame.index} has {n} points; keypoint detection needs at "
                f"least {MIN_POINTS} to form neighbourhoods"
            )
        k = self.budget(n)
        if k == 0:
            return np.empty(0, dtype=np.int64)
        tier, score = self.rank(frame.points)
        return top_k(tier, score, k)
