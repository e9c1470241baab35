"""The metric contract, one top-level check per clause (``check_metric_<what>(metric_cls, params)``).

A frame metric is run on evaluations of the kit's scans -- the original itself (lossless), every
third point (a selection), nothing at all (an empty decode) -- and a sequence metric on a short
synthetic drive with poses, decoded losslessly. Values must be floats, ``None`` where undefined,
never NaN; only declared ids; the same values twice.
"""

from __future__ import annotations

import json
import tracemalloc

import numpy as np

from lwbench.codec import CodecKind
from lwbench.dataset import Dataset
from lwbench.frame import Frame
from lwbench.metric import METRIC_ROLES, Evaluation, FrameMetric, Guard, SequenceEvaluation, SequenceMetric
from lwbench.payload import Payload
from lwbench.points import pack_points
from lwbench.synthetic import check_frames, tunnel_scan

from .base import check, fail

__all__ = [
    "check_metric_declared",
    "check_metric_deterministic",
    "check_metric_streams",
    "check_metric_values",
    "kit_drive",
]


class _KitDrive(Dataset):
    """Four tunnel scans 0.5 m apart along x, with their poses: the sequence metrics' kit."""

    name = "lwbench-kit-drive"

    def __init__(self) -> None:
        super().__init__()
        self._frames = []
        for i in range(4):
            f = tunnel_scan(seed=7)
            pose = np.eye(4)
            pose[0, 3] = 0.5 * i
            self._frames.append(Frame(f.points, f.sensor, index=i, pose=pose, timestamp=0.25 * i))

    def __len__(self) -> int:
        return len(self._frames)

    def frame(self, index: int) -> Frame:
        return self._frames[index]

    @property
    def has_poses(self) -> bool:
        return True


def kit_drive() -> Dataset:
    """The short drive a sequence metric is checked on (4 tunnel scans with ground-truth poses)."""
    return _KitDrive()


def _evaluations() -> list[tuple[str, Evaluation]]:
    """(label, evaluation) for every kit scan decoded losslessly, as every third point, as nothing."""
    out = []
    for label, frame in check_frames().items():
        for what, decoded in (("lossless", frame.points), ("a third", frame.points[::3]),
                              ("empty", np.zeros((0, 3), np.float32))):
            payload = Payload("lwbench-kit", {}, pack_points(decoded)).to_bytes()
            kind = CodecKind.REPRESENTATION if what != "a third" else CodecKind.SELECTION
            out.append((f"{label}, {what}", Evaluation(frame, payload, decoded, kind,
                                                       {"encode_ms": 1.0, "decode_ms": 1.0, "select_ms": 0.5})))
    return out


def _values(metric_cls, params: dict | None) -> list[tuple[str, dict]]:
    metric = metric_cls(**dict(params or {}))
    if issubclass(metric_cls, SequenceMetric):
        drive = kit_drive()
        seq = SequenceEvaluation(drive, list(range(len(drive))), [f.points for f in drive], "lwbench-kit", {})
        return [("the kit's drive, lossless", metric.compute(seq))]
    return [(label, metric.compute(ev)) for label, ev in _evaluations()]


@check("declared", "metric")
def check_metric_declared(metric_cls, params: dict | None = None) -> None:
    """A FrameMetric or SequenceMetric subclass with a name, a version string, unique ids that say
    what they are (lwbench.MetricId: a better direction, a known role, a valid guard that voids
    only its metric's ids), valid declared defaults, and a JSON signature."""
    if not (isinstance(metric_cls, type) and issubclass(metric_cls, (FrameMetric, SequenceMetric))):
        fail("declared", f"{metric_cls!r} is not a lwbench.FrameMetric or SequenceMetric subclass")
    if not getattr(metric_cls, "name", "") or not isinstance(metric_cls.version, str):
        fail("declared", "a metric needs a name and a version string (bump the version when values change)")
    ids = [str(i) for i in metric_cls.ids]
    if not ids or len(set(ids)) != len(ids):
        fail("declared", f"ids must be declared once each, got {ids}")
    for i in metric_cls.ids:
        if not hasattr(i, "better"):
            fail("declared", f"id {i!r} is a plain string: declare lwbench.MetricId(name, unit, better)")
        if getattr(i, "role", "") not in METRIC_ROLES:
            fail("declared", f"id {i}: role {i.role!r} is not one of {METRIC_ROLES}")
        guard = getattr(i, "guard", None)
        if guard is not None and (not isinstance(guard, Guard) or not set(guard.voids) <= set(ids)):
            fail("declared", f"id {i}: a guard may void only its own metric's ids ({guard})")
    for p in metric_cls.params:
        p.validate(p.default)
    metric = metric_cls(**dict(params or {}))
    try:
        json.dumps(metric.signature(), sort_keys=True)
    except (TypeError, ValueError) as exc:
        fail("declared", f"signature() must be JSON (it is part of every row's key): {exc}")


@check("values", "metric")
def check_metric_values(metric_cls, params: dict | None = None) -> None:
    """On the kit's evaluations the metric returns only declared ids, each a float (``+inf``
    allowed: a lossless PSNR) or ``None`` where undefined -- never NaN, which poisons every mean."""
    ids = {str(i) for i in metric_cls.ids}
    for label, values in _values(metric_cls, params):
        if not isinstance(values, dict) or not values:
            fail("values", f"{label}: compute must return a non-empty dict of id -> value, got {values!r}")
        stray = sorted(set(values) - ids)
        if stray:
            fail("values", f"{label}: returned undeclared id(s) {stray}")
        for k, v in values.items():
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer))):
                fail("values", f"{label}: {k} = {v!r} is not a number or None")
            if v is not None and (v != v or v == float("-inf")):
                fail("values", f"{label}: {k} = {v} (return None for an undefined value, never NaN)")


def _same(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return a == b or bool(np.isclose(a, b, rtol=1e-9, atol=1e-12))


@check("deterministic", "metric")
def check_metric_deterministic(metric_cls, params: dict | None = None) -> None:
    """The same evaluations give the same values (a stored row must be reproducible) -- to 1e-9
    relative: a multi-threaded reduction (Open3D's ICP) may round its last digit differently."""
    for (label, a), (_, b) in zip(_values(metric_cls, params), _values(metric_cls, params), strict=True):
        differ = sorted(k for k in set(a) | set(b) if not _same(a.get(k), b.get(k)))
        if differ:
            fail("deterministic", f"{label}: two computations differ in {differ}")


class _LoopDrive(Dataset):
    """``n`` tunnel scans driven back and forth over the same 1.5 m (four poses, repeated): the
    area stays the same however many frames there are, so a metric whose memory follows the area
    (a voxel map) uses the same at every length, and one that keeps scans grows with ``n``."""

    name = "lwbench-kit-loop"

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n
        self.scan = tunnel_scan(seed=7)

    def __len__(self) -> int:
        return self.n

    def pose(self, index: int) -> np.ndarray:
        pose = np.eye(4)
        pose[0, 3] = 0.5 * (index % 4)
        return pose

    def frame(self, index: int) -> Frame:
        return Frame(self.scan.points.copy(), self.scan.sensor, index=index, pose=self.pose(index),
                     timestamp=0.25 * index)

    @property
    def has_poses(self) -> bool:
        return True


def _peak_bytes(metric_cls, params: dict | None, n: int) -> tuple[int, int]:
    """(peak traced bytes of one ``compute`` over an ``n``-frame loop drive, bytes of one scan)."""
    drive = _LoopDrive(n)
    scan = drive.scan.points

    def decode(position: int) -> np.ndarray:
        return scan.copy()  # a fresh array per access, as a decoder returns

    metric = metric_cls(**dict(params or {}))
    seq = SequenceEvaluation(drive, list(range(n)), decode, "lwbench-kit", {})
    tracemalloc.start()
    try:
        metric.compute(seq)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return peak, scan.nbytes


def _not_sequence(metric_cls) -> str:
    return "" if issubclass(metric_cls, SequenceMetric) else "a frame metric sees one frame at a time"


@check("streams", "metric", skip=_not_sequence)
def check_metric_streams(metric_cls, params: dict | None = None) -> None:
    """A sequence metric's memory does not grow with the number of frames: on a drive that stays
    in one place, 16 frames may take no more than 4 frames do plus four scans' worth (a metric
    that keeps the decoded scans -- ``list(seq.decoded)`` -- grows by twelve). What Python and
    NumPy allocate is counted (tracemalloc), so memory a native library keeps is not."""
    _peak_bytes(metric_cls, params, 4)  # first use: imports, caches
    short, one = _peak_bytes(metric_cls, params, 4)
    long, _ = _peak_bytes(metric_cls, params, 16)
    if long - short > 4 * one:
        fail("streams", f"peak memory {short / 2**20:.1f} MiB over 4 frames, {long / 2**20:.1f} MiB over 16 frames "
                        f"of the same place ({(long - short) / one:.0f} scans' worth more): a sequence metric must "
                        "read seq.steps() and keep what grows with the area, not the frames")
