"""The metric interfaces: frame metrics score one decoded scan, sequence metrics a whole run.

Metric ids are a public contract (DESIGN.md): gates and scripts read them, so a metric may add
ids but never rename one. A metric returns ``None`` for a value that is undefined on this input
(e.g. Chamfer distance to an empty cloud) -- never NaN, which would poison every mean.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from lwbench.codec import CodecKind
from lwbench.dataset import Dataset
from lwbench.types import Frame

__all__ = ["Evaluation", "FrameMetric", "SequenceEvaluation", "SequenceMetric"]

MetricValues = dict[str, float | None]


@dataclass
class Evaluation:
    """Everything a frame metric may look at for one (frame, codec configuration)."""

    frame: Frame
    payload: bytes
    decoded: np.ndarray
    codec_kind: CodecKind
    timings_ms: dict[str, float]
    peak_mb: float | None = None
    device: str = "cpu"
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    def cached(self, key: str, compute: Callable[[], Any]) -> Any:
        """Share an expensive intermediate (a KD-tree, a range image) between metrics."""
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]


@dataclass
class SequenceEvaluation:
    """One codec configuration over a whole sequence: originals, decoded scans, poses."""

    dataset: Dataset
    frame_indices: list[int]
    decoded: list[np.ndarray]
    codec_name: str
    params: dict[str, Any]
    seed: int = 0

    def original(self, i: int) -> Frame:
        return self.dataset[self.frame_indices[i]]


class FrameMetric(abc.ABC):
    """Computes a few related metric ids for one frame (they often share intermediates)."""

    name: ClassVar[str]
    ids: ClassVar[tuple[str, ...]]
    description: ClassVar[str] = ""

    @abc.abstractmethod
    def compute(self, ev: Evaluation) -> MetricValues: ...


class SequenceMetric(abc.ABC):
    """Computes metric ids over a sequence (needs ground-truth poses)."""

    name: ClassVar[str]
    ids: ClassVar[tuple[str, ...]]
    description: ClassVar[str] = ""
    params: ClassVar[dict[str, Any]] = {}

    @abc.abstractmethod
    def compute(self, seq: SequenceEvaluation) -> MetricValues: ...
