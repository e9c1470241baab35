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
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
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
    "SequenceStep",
    "QUANTITIES",
    "ids_by_quantity",
    "info_from_declarations",
]

MetricValues = dict[str, float | None]
LOWER, HIGHER = "lower", "higher"
#: What an id is to the report: a ``rate`` axis, a ``distortion`` plotted against the rate, a
#: ``runtime`` bar; ``""`` for everything else.
METRIC_ROLES = ("", "rate", "distortion", "runtime")
#: What an id measures, where core relies on it -- the vocabulary through which core finds an id
#: without writing its name (docs/design.md: core knows no metric by name). At most one installed
#: id declares each quantity; a missing one only switches off what needs it (the noise floor).
QUANTITIES = {
    "range_error_rms": "RMS range error over a scan's returns, m: the distortion the noise floor is drawn against",
    "rate_bits_per_point": "coded bits per input point: the rate of the noise floor",
    "bytes_per_frame": "payload bytes per frame: the rate axis when none is named",
    "input_points": "points in the original scan (a floor in bits per point as bytes per frame)",
    "range_noise_sigma": "the range noise the scan's sensor model declares, m: an input of the noise floor",
    "mask_bits_per_point": "bits per point of the scan's no-return mask: an input of the noise floor",
}
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
    - ``quantity``: one of :data:`QUANTITIES` or ``""`` -- what it measures, where core needs to
      find it (the noise floor, ``lwbench rd``'s default axes) without knowing its name;
    - ``guard``: a :class:`Guard` -- what the id's value says about the whole configuration.
    """

    unit: str
    better: str
    default: bool
    headline: bool
    role: str
    quantity: str
    guard: Guard | None

    def __new__(cls, name: str, unit: str = "", better: str = "", *, default: bool = False, headline: bool = False,
                role: str = "", quantity: str = "", guard: Guard | None = None) -> MetricId:
        if better not in (LOWER, HIGHER, ""):
            raise ValueError(f"metric id {name}: better must be 'lower', 'higher' or '', got {better!r}")
        if role not in METRIC_ROLES:
            raise ValueError(f"metric id {name}: role must be one of {METRIC_ROLES}, got {role!r}")
        if quantity and quantity not in QUANTITIES:
            raise ValueError(f"metric id {name}: quantity must be one of {sorted(QUANTITIES)} or '', got {quantity!r}")
        if guard is not None and not isinstance(guard, Guard):
            raise ValueError(f"metric id {name}: guard must be a lwbench.Guard")
        obj = super().__new__(cls, name)
        obj.unit, obj.better, obj.default = unit, better, default
        obj.headline, obj.role, obj.quantity, obj.guard = headline, role, quantity, guard
        return obj

    def __reduce__(self):  # pickles (worker processes) with its description
        return (MetricId, (str(self), self.unit, self.better),
                {"default": self.default, "headline": self.headline, "role": self.role, "quantity": self.quantity,
                 "guard": self.guard})

    def describe(self) -> dict:
        out = {"id": str(self), "unit": self.unit, "better": self.better, "default": self.default}
        if self.headline:
            out["headline"] = True
        if self.role:
            out["role"] = self.role
        if self.quantity:
            out["quantity"] = self.quantity
        if self.guard is not None:
            out["guard"] = {k: v for k, v in self.guard.__dict__.items() if v not in (None, (), "")}
        return out


def metric_id_from_description(d: Mapping[str, Any]) -> MetricId:
    """The :class:`MetricId` a :meth:`MetricId.describe` dict describes (what a store keeps)."""
    guard = d.get("guard")
    if guard is not None:
        guard = Guard(**{k: tuple(v) if isinstance(v, list) else v for k, v in guard.items()})
    return MetricId(d["id"], d.get("unit", ""), d.get("better", ""), default=bool(d.get("default", False)),
                    headline=bool(d.get("headline", False)), role=d.get("role", ""), quantity=d.get("quantity", ""),
                    guard=guard)


def _version_order(version: Any) -> tuple:
    text = str(version)
    return (0, int(text), "") if text.isdigit() else (1, 0, text)


def info_from_declarations(declarations: Iterable[Mapping[str, Any]]) -> dict[str, MetricId]:
    """Every metric id with its declaration, in board order (each metric's ``order``, then its
    name; ids as the metric declares them), from metric declarations -- a metric's
    :meth:`describe` plus its ``order``, as a registry has them or a store kept them. Of two
    versions of one metric the newer one counts."""
    newest: dict[str, Mapping[str, Any]] = {}
    for d in declarations:
        old = newest.get(d["name"])
        if old is None or _version_order(d.get("version", "")) >= _version_order(old.get("version", "")):
            newest[d["name"]] = d
    ordered = sorted(newest.values(), key=lambda d: (d.get("order", 100), d["name"]))
    return {i["id"]: metric_id_from_description(i) for d in ordered for i in d.get("ids", [])}


def ids_by_quantity(info: Mapping[str, Any]) -> dict[str, str]:
    """The installed id of each declared quantity (:data:`QUANTITIES`), from a board's metric
    info (``Registry.metric_info()``); the first in board order when two declare one."""
    out: dict[str, str] = {}
    for i, declared in info.items():
        quantity = getattr(declared, "quantity", "")
        if quantity:
            out.setdefault(quantity, str(i))
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


@dataclass(frozen=True)
class SequenceStep:
    """One frame of a pass over a sequence: what a streaming sequence metric consumes.

    ``position`` is the frame's place among the evaluated frames (0..n-1), ``index`` its index in
    the dataset; ``decoded`` the codec's decoded cloud (decoded afresh from the stored payload),
    ``pose`` the ground-truth sensor->world pose. The original scan is read only when asked for
    (:attr:`original`): most passes never need it, and on a simulator it costs a ray cast."""

    position: int
    index: int
    decoded: np.ndarray
    pose: np.ndarray
    _dataset: Dataset = field(repr=False, compare=False)

    @property
    def original(self) -> Frame:
        return self._dataset[self.index]


#: Reports a pass's progress: (what the pass is, frames done, frames in the pass).
StepReporter = Callable[[str, int, int], None]


class DecodedScans(Sequence):
    """``seq.decoded``: the decoded clouds as a sequence that holds none of them -- each access
    decodes that frame afresh. Kept for metrics written before :meth:`SequenceEvaluation.steps`;
    a metric that copies it into a list holds the whole drive (the kit's memory check fails it)."""

    def __init__(self, source: Callable[[int], np.ndarray], n: int) -> None:
        self._source, self._n = source, n

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):  # type: ignore[override]
        if isinstance(i, slice):
            return [self._source(k) for k in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(f"decoded scan {i} out of range (0..{self._n - 1})")
        return self._source(i % self._n)


class SequenceEvaluation:
    """One codec configuration over a whole sequence, read as a stream (docs/plugins.md).

    Nothing of the drive is held: :meth:`steps` is one pass over the frames in order, each
    decoded cloud decoded from its stored payload as the pass reaches it, the original read only
    when a step asks. A metric that needs two passes (a map from every scan, then tracking each
    scan against it) calls :meth:`steps` twice. :meth:`poses` are the ground-truth poses (small:
    128 bytes a frame); :meth:`cached` shares what depends only on the originals (ground truth,
    the original map) between the configurations of a run.

    ``decoded`` is either a list of clouds (tests, small drives) or a function position -> cloud.
    """

    def __init__(
        self,
        dataset: Dataset,
        frame_indices: list[int],
        decoded: Sequence[np.ndarray] | Callable[[int], np.ndarray],
        codec_name: str,
        params: dict[str, Any],
        seed: int = 0,
        _cache: dict[str, Any] | None = None,
        on_step: StepReporter | None = None,
        files: Any = None,
    ) -> None:
        self.dataset = dataset
        self.frame_indices = list(frame_indices)
        self.codec_name, self.params, self.seed = codec_name, params, seed
        self._cache: dict[str, Any] = {} if _cache is None else _cache
        self.on_step = on_step
        self._files = files  # a lwbench.results.artifacts.CloudFiles every task of the run reads, or None
        if callable(decoded):
            self._decode = decoded
        else:
            clouds = list(decoded)
            if len(clouds) != len(self.frame_indices):
                raise ValueError(f"{len(clouds)} decoded clouds for {len(self.frame_indices)} frames")
            self._decode = clouds.__getitem__
        self.decoded = DecodedScans(self._decode, len(self.frame_indices))

    def __len__(self) -> int:
        return len(self.frame_indices)

    def original(self, i: int) -> Frame:
        """The original frame at position ``i`` (read from the dataset each time)."""
        return self.dataset[self.frame_indices[i]]

    def poses(self) -> np.ndarray:
        """Ground-truth poses ``(n, 4, 4)`` of the evaluated frames (:meth:`Dataset.pose`)."""

        def read() -> np.ndarray:
            poses = [self.dataset.pose(i) for i in self.frame_indices]
            if any(p is None for p in poses):
                raise ValueError(f"{self.dataset.name}: sequence metrics need ground-truth poses on every frame")
            return np.stack(poses).astype(np.float64)

        return self.cached("poses", read)

    def steps(self, positions: Sequence[int] | None = None, what: str = "pass") -> Iterator[SequenceStep]:
        """One pass over ``positions`` (default: every frame), in order, decoding as it goes.
        ``what`` names the pass in the run's progress (``map``, ``tracking``)."""
        chosen = range(len(self)) if positions is None else list(positions)
        poses = self.poses()
        n = len(chosen)
        for k, p in enumerate(chosen):
            if self.on_step is not None:
                self.on_step(what, k, n)
            yield SequenceStep(p, self.frame_indices[p], self._decode(p), poses[p], self.dataset)
        if self.on_step is not None:
            self.on_step(what, n, n)

    def originals(self, positions: Sequence[int] | None = None, what: str = "originals") -> Iterator[SequenceStep]:
        """A pass over the *original* scans (``decoded`` is the original's points): what the
        metrics compute once per run on the originals goes through the same code as a codec's."""
        chosen = range(len(self)) if positions is None else list(positions)
        poses = self.poses()
        n = len(chosen)
        for k, p in enumerate(chosen):
            if self.on_step is not None:
                self.on_step(what, k, n)
            frame = self.original(p)
            yield SequenceStep(p, self.frame_indices[p], frame.points, poses[p], self.dataset)
        if self.on_step is not None:
            self.on_step(what, n, n)

    def keep(self, array: np.ndarray) -> str:
        """Keep an array where every task of this run can read it back (:meth:`fetch`), and
        return its name: a file beside the results store (content-addressed), or -- a store in
        memory -- this run's cache. For what a :meth:`cached` value should refer to rather than
        hold: the original occupancy map of a long drive is tiles of keys, not one array."""
        from lwbench.results.artifacts import digest_of

        if self._files is not None:
            return self._files.put(array)
        name = digest_of(array)
        self._cache[f"kept:{name}"] = np.asarray(array)
        return name

    def fetch(self, name: str) -> np.ndarray:
        """An array :meth:`keep` kept (``KeyError`` if it is gone)."""
        if self._files is not None:
            array = self._files.get(name)
            if array is None:
                raise KeyError(f"kept array {name} is gone from {self._files.folder}")
            return array
        return self._cache[f"kept:{name}"]

    def cached(self, key: str, compute: Callable[[], Any]) -> Any:
        """An intermediate that depends only on the original scans (and ``key``). Values must
        pickle: a run computes each once and hands it to the workers that need it."""
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
    def declaration(cls) -> dict:
        """What a store keeps of this metric (:meth:`describe` and ``order``): enough to rank,
        sort and flag its ids where the metric is not installed."""
        return {**cls.describe(), "order": cls.order}

    @classmethod
    def describe(cls) -> dict:
        out = {
            "name": cls.name,
            "version": cls.version,
            "ids": [as_metric_id(i).describe() for i in cls.ids],
            "description": cls.description,
            "params": [p.describe() for p in cls.params],
        }
        if not getattr(cls, "in_default_run", True):
            out["in_default_run"] = False
        return out


class FrameMetric(_Metric, abc.ABC):
    """Computes a few related metric ids for one frame (they often share intermediates)."""

    @abc.abstractmethod
    def compute(self, ev: Evaluation) -> MetricValues: ...


class SequenceMetric(_Metric, abc.ABC):
    """Computes metric ids over a sequence (needs ground-truth poses), as a stream.

    ``compute`` reads the sequence through :meth:`SequenceEvaluation.steps` -- one pass per call,
    frames in order -- and keeps bounded state: what grows with the area covered (a voxel map),
    never what grows with the number of frames (a list of scans). A run of 5,000 scans must fit
    on a laptop; ``lwbench.testing`` checks a metric's memory does not grow with frames.
    Each (configuration, metric) is one task of the run's sequence stage, run on ``--workers``
    processes or Ray like the frames.

    ``in_default_run``: whether a run with poses computes it unless told otherwise. A metric that
    is slow for what most runs ask (KISS-ICP: +30 % on the README's main job) declares ``False`` and
    runs only when named (``lwbench run --metric NAME``, a run file's ``metrics = [...]``) -- the
    same declaration a codec makes, so no part of lwbench knows such a metric by name."""

    in_default_run: ClassVar[bool] = True

    @abc.abstractmethod
    def compute(self, seq: SequenceEvaluation) -> MetricValues: ...
