"""The metric interfaces: frame metrics score one decoded scan, sequence metrics a whole run.

Metric ids are a public contract (docs/design.md): gates and scripts read them, so a metric may
add ids but never rename one. What an id *means* to the board is declared with it
(:class:`MetricId`: unit, better direction, default column, headline, role, quality
:class:`Guard`), so no part of lwbench knows a metric by name. A metric returns ``None`` for a
value that is undefined on this input (e.g. Chamfer distance to an empty cloud) -- never NaN,
which would poison every mean.

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

__all__ = [
    "ALL_CURVES",
    "Evaluation",
    "FrameMetric",
    "Guard",
    "HIGHER",
    "LOWER",
    "METRIC_ROLES",
    "MetricId",
    "SequenceEvaluation",
    "SequenceMetric",
]

MetricValues = dict[str, float | None]
LOWER, HIGHER = "lower", "higher"
#: What an id is to the report: a ``rate`` axis, a ``distortion`` plotted against the rate, a
#: ``runtime`` bar; ``""`` for everything else.
METRIC_ROLES = ("", "rate", "distortion", "runtime")
#: ``Guard.off_curves`` value: a flagged configuration is left off every rate-distortion curve.
ALL_CURVES = "*"


@dataclass(frozen=True)
class Guard:
    """What one id's value says about a whole configuration on the board: the quality guard.

    A configuration whose mean of the id is below ``below`` (or above ``above``) gets the flag
    ``flag`` (shown as ``text``); flagged configurations rank after the others. Its figures of the
    ids in ``voids`` then mean nothing (shown ``n/m``, never ranked); the rate-distortion curves of
    the ids in ``off_curves`` (:data:`ALL_CURVES`: all) leave it out. ``setting`` names the board
    setting that replaces the limit (``min_coverage``: ``lwbench leaderboard --min-coverage``)."""

    flag: str
    text: str
    below: float | None = None
    above: float | None = None
    voids: tuple[str, ...] = ()
    off_curves: tuple[str, ...] = ()
    setting: str = ""

    def __post_init__(self) -> None:
        if (self.below is None) == (self.above is None):
            raise ValueError(f"guard {self.flag}: give exactly one of below= and above=")
        if not self.flag or not self.text:
            raise ValueError("a guard needs a flag name and its text")

    def raised(self, value: float | None, limit: float | None = None) -> bool:
        """Whether a configuration with this mean is flagged (``limit``: the setting's value)."""
        if value is None:
            return False
        if self.below is not None:
            return value < (self.below if limit is None else limit)
        return value > (self.above if limit is None else limit)


class MetricId(str):
    """A metric id that says what it is -- so a third-party metric sorts, prints, plots and guards
    correctly without lwbench knowing its name. It *is* the id string (a dict key, in JSON).

    - ``unit``; ``better``: ``"lower"``, ``"higher"`` or ``""`` (a count with no better direction);
    - ``default``: a column of the default board; ``headline``: what a board is sorted by when
      no ``--sort`` is given (one id: the compression ratio);
    - ``role``: one of :data:`METRIC_ROLES` (what the HTML report draws it as);
    - ``guard``: a :class:`Guard` -- what the id's value says about the whole configuration.
    """

    unit: str
    better: str
    default: bool
    headline: bool
    role: str
    guard: Guard | None

    def __new__(cls, name: str, unit: str = "", better: str = "", *, default: bool = False, headline: bool = False,
                role: str = "", guard: Guard | None = None) -> MetricId:
        if better not in (LOWER, HIGHER, ""):
            raise ValueError(f"metric id {name}: better must be 'lower', 'higher' or '', got {better!r}")
        if role not in METRIC_ROLES:
            raise ValueError(f"metric id {name}: role must be one of {METRIC_ROLES}, got {role!r}")
        if guard is not None and not isinstance(guard, Guard):
            raise ValueError(f"metric id {name}: guard must be a lwbench.Guard")
        obj = super().__new__(cls, name)
        obj.unit, obj.better, obj.default = unit, better, default
        obj.headline, obj.role, obj.guard = headline, role, guard
        return obj

    def __reduce__(self):  # pickles (worker processes) with its description
        return (MetricId, (str(self), self.unit, self.better),
                {"default": self.default, "headline": self.headline, "role": self.role, "guard": self.guard})

    def describe(self) -> dict:
        out = {"id": str(self), "unit": self.unit, "better": self.better, "default": self.default}
        if self.headline:
            out["headline"] = True
        if self.role:
            out["role"] = self.role
        if self.guard is not None:
            out["guard"] = {k: v for k, v in self.guard.__dict__.items() if v not in (None, (), "")}
        return out


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
