"""The codec contract, one top-level check per clause (``check_codec_<what>(codec_cls, params)``).

Each runs on the kit's scans (:func:`lwbench.synthetic.check_frames`: an off-grid room, the same
with exact duplicates, a 32-beam ring scan with a derived sensor named by id), decodes with a
*fresh* instance handed only the scan's sensor (as a receiver is), and raises
:class:`~lwbench.testing.ConformanceError` on a breach. Which apply follows from what the codec
declares: a codec that ``needs`` something a scan does not have (labels) is only checked for its
declarations; the selection checks apply to selection codecs, the budget check to those that
declare :data:`lwbench.BUDGET_PARAMS`.
"""

from __future__ import annotations

import numpy as np

from lwbench.codec import Codec, SelectionCodec
from lwbench.errors import LwbenchError, PayloadError
from lwbench.frame import Frame
from lwbench.payload import Payload
from lwbench.sensors.model import get_sensor
from lwbench.synthetic import check_frames

from .base import check, fail

# Its public names are exported, and listed, by lwbench.testing.

#: The conformance kit's fuzz check: at most this many crafted payloads, for at most this long
#: (``lwbench fuzz`` runs the long campaigns).
FUZZ_CASES = 400
FUZZ_SECONDS = 3.0


def codec_skip(codec_cls: type) -> str:
    """Why a check that runs the codec on the kit's scans does not apply (``""``: it does)."""
    needs = getattr(codec_cls, "needs", "")
    return f"{getattr(codec_cls, 'name', codec_cls)} cannot run on an arbitrary scan: it needs {needs}" if needs else ""


def _selection_skip(codec_cls: type) -> str:
    if not (isinstance(codec_cls, type) and issubclass(codec_cls, SelectionCodec)):
        return "not a selection codec"
    return codec_skip(codec_cls)


def _budget_skip(codec_cls: type) -> str:
    if not {"ratio", "points"} <= {p.name for p in getattr(codec_cls, "all_params", tuple)()}:
        return "declares no ratio/points budget (lwbench.BUDGET_PARAMS)"
    return _selection_skip(codec_cls)


def _decode(codec_cls, params: dict, frame: Frame, data: bytes, encoder: Codec | None = None) -> np.ndarray:
    """Decode as a receiver does: a fresh instance that knows only the scan's sensor and the
    tables the encoder's payloads named (what a stream's header carries)."""
    sensors = [frame.sensor, *(encoder.sensors if encoder is not None else ())]
    return codec_cls(**params).use_sensors(sensors).decode(data)


def _encoded(codec_cls, params: dict, frame: Frame) -> tuple[bytes, Codec]:
    encoder = codec_cls(**params)
    return encoder.encode(frame), encoder


@check("declared", "codec")
def check_codec_declared(codec_cls, params: dict | None = None) -> None:
    """A Codec subclass with a name, a version string, valid declared defaults, a matching
    ``describe()``, and an ``__init__`` that accepts ``params``."""
    if not (isinstance(codec_cls, type) and issubclass(codec_cls, Codec)):
        fail("declared", f"{codec_cls!r} is not a lwbench.Codec subclass")
    if not getattr(codec_cls, "name", "") or not isinstance(codec_cls.version, str):
        fail("declared", "a codec needs a name and a version string (bump the version when output changes)")
    info = codec_cls.describe()
    for p in codec_cls.all_params():
        p.validate(p.default)  # every default is a legal value
    if info["name"] != codec_cls.name:
        fail("declared", "describe() must report the codec's own name")
    codec_cls(**dict(params or {}))


@check("payloads", "codec", codec_skip)
def check_codec_payloads(codec_cls, params: dict | None = None) -> None:
    """Bytes that parse as an lwbench payload of this codec, which a fresh instance decodes from
    the bytes (and the scan's sensor) alone to a non-empty finite float32 ``(M, 3)`` cloud."""
    params = dict(params or {})
    for label, frame in check_frames().items():
        data, encoder = _encoded(codec_cls, params, frame)
        if not isinstance(data, bytes):
            fail("payloads", f"{label}: encode returned {type(data).__name__}, not bytes")
        if Payload.from_bytes(data).codec_id != codec_cls.name:
            fail("payloads", f"{label}: the payload names another codec")
        cloud = _decode(codec_cls, params, frame, data, encoder)
        if not (isinstance(cloud, np.ndarray) and cloud.ndim == 2 and cloud.shape[1] == 3):
            fail("payloads", f"{label}: decode must return an (M, 3) array, got {getattr(cloud, 'shape', cloud)}")
        if cloud.dtype != np.float32 or not np.isfinite(cloud).all() or len(cloud) == 0:
            fail("payloads", f"{label}: decode must return finite float32 points ({cloud.dtype}, {len(cloud)})")


@check("own_payloads", "codec", codec_skip)
def check_codec_decodes_own_payloads(codec_cls, params: dict | None = None) -> None:
    """Every payload the codec writes on the kit's scans -- with ``params`` and with each declared
    choice or flag changed in turn -- decodes with that codec. An encoder may refuse a scan (an
    lwbench error or ``ValueError`` with a message); it may not write a payload its own decoder
    then refuses (VSGP's decoder once refused every payload its encoder wrote for a guessed
    243-beam sensor: the encoder must check the bound its decoder applies, or adapt)."""
    from lwbench.fuzz import parameter_variants

    for variant in parameter_variants(codec_cls, dict(params or {})):
        changed = {k: v for k, v in variant.items() if (params or {}).get(k, object()) != v} or "the given parameters"
        for label, frame in check_frames().items():
            try:
                data, encoder = _encoded(codec_cls, variant, frame)
            except (LwbenchError, ValueError) as exc:
                if not str(exc):
                    fail("own_payloads", f"{label} with {changed}: refused the scan without a message")
                continue
            try:
                _decode(codec_cls, variant, frame, data, encoder)
            except PayloadError as exc:
                fail("own_payloads", f"{label} with {changed}: the decoder refuses the encoder's own payload ({exc})")


@check("deterministic", "codec", codec_skip)
def check_codec_deterministic(codec_cls, params: dict | None = None) -> None:
    """Two encodes of one scan give the same bytes, two decodes of one payload the same cloud."""
    params = dict(params or {})
    for label, frame in check_frames().items():
        data, encoder = _encoded(codec_cls, params, frame)
        if codec_cls(**params).encode(frame) != data:
            fail("deterministic", f"{label}: two encodes of one frame differ (seed every random choice)")
        if not np.array_equal(_decode(codec_cls, params, frame, data, encoder),
                              _decode(codec_cls, params, frame, data, encoder)):
            fail("deterministic", f"{label}: two decodes of one payload differ")


@check("corrupt", "codec", codec_skip)
def check_codec_corrupt(codec_cls, params: dict | None = None) -> None:
    """Truncated, bit-flipped, foreign and empty payloads raise ``PayloadError`` (nothing else)."""
    params = dict(params or {})
    data = codec_cls(**params).encode(check_frames()["room"])
    mid = bytearray(data)
    mid[len(mid) // 2] ^= 0x10
    foreign = Payload("not-" + codec_cls.name, {}, b"\x00" * 16).to_bytes()
    for what, bad in (("truncated", data[: len(data) // 2]), ("one byte short", data[:-1]),
                      ("bit flipped", bytes(mid)), ("checksum flipped", data[:-1] + bytes([data[-1] ^ 1])),
                      ("another codec's payload", foreign), ("empty", b"")):
        try:
            codec_cls(**params).decode(bad)
        except PayloadError:
            continue
        except Exception as exc:  # noqa: BLE001 - the point of the check
            fail("corrupt", f"{what}: raised {type(exc).__name__} ({exc}), not lwbench.PayloadError")
        fail("corrupt", f"{what}: decoded without an error")


@check("empty_scan", "codec", codec_skip)
def check_codec_empty_scan(codec_cls, params: dict | None = None) -> None:
    """An empty scan is encoded to a payload that decodes to a finite (M, 3) cloud, or refused
    with a message."""
    params = dict(params or {})
    empty = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    try:
        data, encoder = _encoded(codec_cls, params, empty)
    except (LwbenchError, ValueError) as exc:
        if not str(exc):
            fail("empty_scan", "refused an empty scan without a message")
        return
    cloud = _decode(codec_cls, params, empty, data, encoder)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or not np.isfinite(cloud).all():
        fail("empty_scan", "an empty scan's payload must decode to an (M, 3) finite cloud")


@check("selection", "codec", _selection_skip)
def check_codec_selection(codec_cls, params: dict | None = None) -> None:
    """A selector returns unique indices into the scan."""
    params = dict(params or {})
    for label, frame in check_frames().items():
        idx = np.asarray(codec_cls(**params).select(frame))
        in_range = not len(idx) or (idx.min() >= 0 and idx.max() < len(frame))
        if idx.ndim != 1 or len(np.unique(idx)) != len(idx) or not in_range:
            fail("selection", f"{label}: select must return unique indices into the scan")


@check("budget", "codec", _budget_skip)
def check_codec_budget(codec_cls, params: dict | None = None) -> None:
    """A ``points=`` budget is met exactly."""
    params = dict(params or {})
    for label, frame in check_frames().items():
        k = max(1, len(frame) // 7)
        got = len(codec_cls(**{**params, "points": k}).select(frame))
        if got != k:
            fail("budget", f"{label}: points={k} kept {got} points (a budget is met exactly)")


@check("scored", "codec", codec_skip)
def check_codec_scored(codec_cls, params: dict | None = None) -> None:
    """Every installed frame metric scores the decoded cloud (values or ``None``, never NaN)."""
    from lwbench.metric import Evaluation
    from lwbench.registry import get_registry

    params = dict(params or {})
    for label, frame in check_frames().items():
        data, encoder = _encoded(codec_cls, params, frame)
        decoded = _decode(codec_cls, params, frame, data, encoder)
        ev = Evaluation(frame, data, decoded, codec_cls.kind, {"encode_ms": 1.0})
        for metric in get_registry().frame_metric_instances():
            values = metric.compute(ev)
            nan = [k for k, v in values.items() if v is not None and v != v]
            if not values or nan:
                fail("scored", f"{label}: metric {metric.name} gave {'NaN for ' + str(nan) if nan else 'nothing'}")


@check("fuzz", "codec", codec_skip)
def check_codec_fuzz(codec_cls, params: dict | None = None) -> None:
    """Crafted payloads (CRC recomputed) decoded out of process: only ``PayloadError`` escapes,
    nothing decodes to a cloud no LiDAR returns (``absurd``: beyond the payload's sensor's reach,
    or 10 km), within a second of CPU and 512 MB. Bounded (a few seconds), so it fits any CI."""
    from lwbench.fuzz import fuzz_codec, shared_server

    report = fuzz_codec(codec_cls, params, cases=FUZZ_CASES, seconds=FUZZ_SECONDS, server=shared_server())
    if report.other:
        worst = "; ".join(f"{v}: {m[:120]}" for v, m, _ in report.failures[:3])
        fail("fuzz", f"{report.summary()} -- e.g. {worst}")
