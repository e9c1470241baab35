"""The metric interfaces: frame metrics score one decoded scan, sequence metrics a whole run.

Metric ids are a public contract (DESIGN.md): gates and scripts read them, so a metric may add
ids but never rename one. A metric returns ``None`` for a value that is undefined on this input
(e.g. Chamfer distance to an empty cloud) -- never NaN, which would poison every mean.

How a row was scored is part of its identity: a metric declares a ``version`` (bump it whenever
a change alters its values) and its user-settable ``params`` (``lwbench run --metric-param
NAME.KEY=VALUE``); sequence metrics may also carry fixed ``settings`` (e.g. the ICP parameters).
:meth:`signature` of all three goes into the store key, so a fixed metric or a changed setting
recomputes instead of being served from the cache, and rows scored two ways are never averaged.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from lwbench.codec import CodecKind
from lwbench.dataset import Dataset
from lwbench.types import Frame, Param, resolve_params

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


class _Metric:
    """What frame and sequence metrics share: a name, ids, a version and declared parameters."""

    name: ClassVar[str]
    ids: ClassVar[tuple[str, ...]]
    description: ClassVar[str] = ""
    version: ClassVar[str] = "1"
    params: ClassVar[tuple[Param, ...]] = ()
    settings: ClassVar[dict[str, Any]] = {}

    def __init__(self, **params: Any) -> None:
        self.config: dict[str, Any] = resolve_params(f"metric {self.name}", self.params, params)

    def signature(self) -> list:
        """``[name, version, params, settings]``: everything that decides this metric's values."""
        return [self.name, self.version, self.config, self.settings]

    @classmethod
    def describe(cls) -> dict:
        return {
            "name": cls.name,
            "version": cls.version,
            "ids": list(cls.ids),
            "description": cls.description,
            "params": [p.describe() for p in cls.params],
        }


class FrameMetric(_Metric, abc.ABC):
    """Computes a few related metric ids for one frame (they often share intermediates)."""

    @abc.abstractmethod
    def compute(self, ev: Evaluation) -> MetricValues: ...


class SequenceMetric(_Metric, abc.ABC):
    """Computes metric ids over a sequence (needs ground-truth poses)."""

    @abc.abstractmethod
    def compute(self, seq: SequenceEvaluation) -> MetricValues: ...
