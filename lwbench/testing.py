"""Small synthetic scans for tests -- lwbench's and a plugin author's own.

Every scan here is intersected in closed form (no ray-casting library), costs milliseconds and
is exactly reproducible from its seed:

- :func:`room_scan` -- a box room; with ``off_grid`` (the default) it looks like a real sensor's
  scan: firings drift against any fixed grid and each laser has its own azimuth and elevation
  offset, so a test can check that a codec or metric does not depend on where cell edges fall
  (the simulator casts every ray through a range-image cell centre; real sensors do not);
- :func:`tunnel_scan` -- an elliptic mine tunnel with a floor and rough walls (VSGP's setting);
- :func:`cylinder_scan` -- a smooth vertical wall around the sensor, optionally only half of it.

And the conformance kit a third-party plugin runs in its own tests, as scikit-learn ships
``check_estimator``: :func:`check_codec` / :func:`check_dataset` (or :func:`codec_checks` /
:func:`dataset_checks` for one pytest case per check). Its ``fuzz`` check decodes a few hundred
crafted payloads out of process (:mod:`lwbench.fuzz`): only ``PayloadError`` may escape.
This repository's own conformance tests call the same functions over every registered plugin.
"""

from __future__ import annotations

import numpy as np

from lwbench.frame import Frame
from lwbench.sensor import get_sensor
from lwbench.synthetic import (
    HDL32_NOMINAL,
    NO_RETURN,
    ROOM_HALF_EXTENT,
    check_frames,
    cylinder_scan,
    hdl32_ring_scan,
    room_scan,
    tunnel_ranges,
    tunnel_scan,
    with_exact_duplicates,
)

__all__ = [
    "ROOM_HALF_EXTENT",
    "ConformanceError",
    "FUZZ_CASES",
    "FUZZ_SECONDS",
    "check_codec",
    "check_dataset",
    "check_frames",
    "codec_checks",
    "cylinder_scan",
    "dataset_checks",
    "HDL32_NOMINAL",
    "NO_RETURN",
    "hdl32_ring_scan",
    "room_scan",
    "tunnel_ranges",
    "tunnel_scan",
    "with_exact_duplicates",
]

#: The conformance kit's fuzz check: at most this many crafted payloads, for at most this long
#: (tools/fuzz_codecs.py runs the long campaigns).
FUZZ_CASES = 400
FUZZ_SECONDS = 3.0


# -- the plugin author's kit: conformance checks (as scikit-learn's check_estimator) -------------
class ConformanceError(AssertionError):
    """A plugin breaks lwbench's contract; the message says which check and how."""


def _fail(check: str, message: str) -> None:
    raise ConformanceError(f"{check}: {message}")


def codec_checks(codec_cls, params: dict | None = None) -> list[tuple[str, object]]:
    """``(name, check)`` pairs, each ``check()`` raising :class:`ConformanceError` on a breach,
    so a test suite can parametrize over them (one test per check)."""
    from lwbench.codec import Codec, SelectionCodec
    from lwbench.errors import LwbenchError, PayloadError
    from lwbench.payload import Payload

    params = dict(params or {})

    def declared() -> None:
        if not (isinstance(codec_cls, type) and issubclass(codec_cls, Codec)):
            _fail("declared", f"{codec_cls!r} is not a lwbench.Codec subclass")
        if not getattr(codec_cls, "name", "") or not isinstance(codec_cls.version, str):
            _fail("declared", "a codec needs a name and a version string (bump the version when output changes)")
        info = codec_cls.describe()
        for p in codec_cls.all_params():
            p.validate(p.default)  # every default is a legal value
        if info["name"] != codec_cls.name:
            _fail("declared", "describe() must report the codec's own name")
        codec_cls(**params)

    def payloads() -> None:
        for label, frame in check_frames().items():
            data = codec_cls(**params).encode(frame)
            if not isinstance(data, bytes):
                _fail("payloads", f"{label}: encode returned {type(data).__name__}, not bytes")
            if Payload.from_bytes(data).codec_id != codec_cls.name:
                _fail("payloads", f"{label}: the payload names another codec")
            cloud = codec_cls(**params).use_sensors([frame.sensor]).decode(data)  # fresh: only the bytes cross
            if not (isinstance(cloud, np.ndarray) and cloud.ndim == 2 and cloud.shape[1] == 3):
                _fail("payloads", f"{label}: decode must return an (M, 3) array, got {getattr(cloud, 'shape', cloud)}")
            if cloud.dtype != np.float32 or not np.isfinite(cloud).all() or len(cloud) == 0:
                _fail("payloads", f"{label}: decode must return finite float32 points ({cloud.dtype}, {len(cloud)})")

    def deterministic() -> None:
        for label, frame in check_frames().items():
            data = codec_cls(**params).encode(frame)
            if codec_cls(**params).encode(frame) != data:
                _fail("deterministic", f"{label}: two encodes of one frame differ (seed every random choice)")
            a, b = (codec_cls(**params).use_sensors([frame.sensor]).decode(data) for _ in range(2))
            if not np.array_equal(a, b):
                _fail("deterministic", f"{label}: two decodes of one payload differ")

    def corrupt() -> None:
        frame = check_frames()["room"]
        data = codec_cls(**params).encode(frame)
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
                _fail("corrupt", f"{what}: raised {type(exc).__name__} ({exc}), not lwbench.PayloadError")
            _fail("corrupt", f"{what}: decoded without an error")

    def empty_scan() -> None:
        empty = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
        try:
            data = codec_cls(**params).encode(empty)
        except (LwbenchError, ValueError) as exc:
            if not str(exc):
                _fail("empty_scan", "refused an empty scan without a message")
            return
        cloud = codec_cls(**params).use_sensors([empty.sensor]).decode(data)
        if cloud.ndim != 2 or cloud.shape[1] != 3 or not np.isfinite(cloud).all():
            _fail("empty_scan", "an empty scan's payload must decode to an (M, 3) finite cloud")

    def selection() -> None:
        if not issubclass(codec_cls, SelectionCodec):
            return
        for label, frame in check_frames().items():
            idx = np.asarray(codec_cls(**params).select(frame))
            in_range = not len(idx) or (idx.min() >= 0 and idx.max() < len(frame))
            if idx.ndim != 1 or len(np.unique(idx)) != len(idx) or not in_range:
                _fail("selection", f"{label}: select must return unique indices into the scan")
            if {"ratio", "points"} <= {p.name for p in codec_cls.all_params()}:
                k = max(1, len(frame) // 7)
                got = len(codec_cls(**{**params, "points": k}).select(frame))
                if got != k:
                    _fail("selection", f"{label}: points={k} kept {got} points (a budget is met exactly)")

    def scored() -> None:
        from lwbench.metric import Evaluation
        from lwbench.registry import get_registry

        for label, frame in check_frames().items():
            data = codec_cls(**params).encode(frame)
            decoded = codec_cls(**params).use_sensors([frame.sensor]).decode(data)
            ev = Evaluation(frame, data, decoded, codec_cls.kind, {"encode_ms": 1.0})
            for metric in get_registry().frame_metric_instances():
                values = metric.compute(ev)
                nan = [k for k, v in values.items() if v is not None and v != v]
                if not values or nan:
                    _fail("scored", f"{label}: metric {metric.name} gave {'NaN for ' + str(nan) if nan else 'nothing'}")

    def fuzz() -> None:
        # Crafted payloads (CRC recomputed) decoded out of process: only PayloadError may escape,
        # within a second of CPU and 512 MB. Bounded (a few seconds), so it fits any CI.
        from lwbench.fuzz import fuzz_codec, shared_server

        report = fuzz_codec(codec_cls, params, cases=FUZZ_CASES, seconds=FUZZ_SECONDS, server=shared_server())
        if report.other:
            worst = "; ".join(f"{v}: {m[:120]}" for v, m, _ in report.failures[:3])
            _fail("fuzz", f"{report.summary()} -- e.g. {worst}")

    checks = [declared, payloads, deterministic, corrupt, empty_scan, selection, scored, fuzz]
    return [(f.__name__, f) for f in checks]


def check_codec(codec_cls, params: dict | None = None) -> None:
    """Run every contract check on a codec class (raises :class:`ConformanceError`).

    Call it from a plugin's own tests -- ``check_codec(MyCodec)`` -- with ``params`` for
    settings that keep the check fast (the contract does not depend on model size)."""
    for _, check in codec_checks(codec_cls, params):
        check()


def dataset_checks(dataset_cls, params: dict | None = None) -> list[tuple[str, object]]:
    """``(name, check)`` pairs for a dataset class with the given parameters."""
    from lwbench.dataset import Dataset

    params = dict(params or {})

    def declared() -> None:
        if not (isinstance(dataset_cls, type) and issubclass(dataset_cls, Dataset)):
            _fail("declared", f"{dataset_cls!r} is not a lwbench.Dataset subclass")
        if not getattr(dataset_cls, "name", ""):
            _fail("declared", "a dataset needs a name")
        dataset_cls.describe()
        from pathlib import Path

        if not isinstance(dataset_cls.sniff(Path("/nonexistent/lwbench-check")), bool):
            _fail("declared", "sniff() must answer True or False (and never raise) for any path")

    def frames() -> None:
        ds = dataset_cls(**params)
        n = len(ds)
        if n < 1:
            _fail("frames", "a dataset with these parameters has no frames")
        for i in sorted({0, n - 1}):
            f = ds[i]
            if not isinstance(f, Frame) or f.index != i:
                _fail("frames", f"frame {i}: expected a Frame with index {i}")
            if ds.has_poses and f.pose is None:
                _fail("frames", f"frame {i}: has_poses is true but the frame has no pose")
        try:
            ds[n]
        except IndexError:
            pass
        else:
            _fail("frames", "indexing past the end must raise IndexError")

    def deterministic() -> None:
        a, b = dataset_cls(**params), dataset_cls(**params)
        if a.identity() != b.identity() or not isinstance(a.identity(), str):
            _fail("deterministic", "identity() must be the same string for the same parameters")
        if not np.array_equal(a[0].points, b[0].points):
            _fail("deterministic", "the same parameters must give the same frames")

    checks = [declared, frames, deterministic]
    return [(f.__name__, f) for f in checks]


def check_dataset(dataset_cls, params: dict | None = None) -> None:
    """Run every contract check on a dataset class (raises :class:`ConformanceError`)."""
    for _, check in dataset_checks(dataset_cls, params):
        check()
