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
from lwbench.frame import Frame
from lwbench.params import Param, resolve_params

__all__ = ["Evaluation", "FrameMetric", "MetricId", "SequenceEvaluation", "SequenceMetric", "LOWER", "HIGHER"]

MetricValues = dict[str, float | None]
LOWER, HIGHER = "lower", "higher"


class MetricId(str):
    """A metric id that says what it is: its unit, which direction is better, and whether the
    leaderboard shows it by default -- so a third-party metric sorts and prints correctly
    without lwbench knowing its name. It *is* the id string (usable as a dict key, in JSON).

    ``better`` is ``"lower"``, ``"higher"`` or ``""`` (a count with no better direction).
    """

    unit: str
    better: str
    default: bool

    def __new__(cls, name: str, unit: str = "", better: str = "", *, default: bool = False) -> MetricId:
        if better not in (LOWER, HIGHER, ""):
            raise ValueError(f"metric id {name}: better must be 'lower', 'higher' or '', got {better!r}")
        obj = super().__new__(cls, name)
        obj.unit, obj.better, obj.default = unit, better, default
        return obj

    def __reduce__(self):  # pickles (worker processes) with its description
        return (MetricId, (str(self), self.unit, self.better), {"default": self.default})

    def describe(self) -> dict:
        return {"id": str(self), "unit": self.unit, "better": self.better, "default": self.default}


def as_metric_id(i: str) -> MetricId:
    """Plain strings (older plugins) become ids with no unit and no direction."""
    return i if isinstance(i, MetricId) else MetricId(i)


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
    """One codec configuration over a whole sequence: originals, decoded scans, poses.

    :meth:`cached` shares what depends only on the originals (ground truth, the original map)
    between the configurations of a run: the cache belongs to the run's sequence stage, which
    creates one per dataset and frame selection.
    """

    dataset: Dataset
    frame_indices: list[int]
    decoded: list[np.ndarray]
    codec_name: str
    params: dict[str, Any]
    seed: int = 0
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    def original(self, i: int) -> Frame:
        return self.dataset[self.frame_indices[i]]

    def cached(self, key: str, compute: Callable[[], Any]) -> Any:
        """An intermediate that depends only on the original scans (and ``key``)."""
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]


class _Metric:
    """What frame and sequence metrics share: a name, ids, a version and declared parameters."""

    name: ClassVar[str]
    ids: ClassVar[tuple[str, ...]]  # MetricId (or plain str: no unit, no direction)
    description: ClassVar[str] = ""
    version: ClassVar[str] = "1"
    # Where the metric's columns go on the leaderboard, left to right (built-ins: 10-60).
    order: ClassVar[int] = 100
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
            "ids": [as_metric_id(i).describe() for i in cls.ids],
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
