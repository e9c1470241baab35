"""Fuzz campaigns: seed payloads from small scans, mutated cases decoded by a :class:`DecodeServer`.

:func:`fuzz_codec` is a whole campaign against one codec: seed payloads encoded from
:func:`fuzz_frames` with the codec's declared parameter choices, then mutated cases until a count
or a time budget; its :class:`FuzzReport` counts outcomes (``ok``, ``PayloadError``, ``absurd`` and
everything else) and verdicts.
"""

from __future__ import annotations

import json
import random
import time
import zlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .mutate import RandomChooser, mutate, split_payload
from .server import DecodeServer, Outcome, class_ref

__all__ = ["FuzzReport", "fuzz_codec", "fuzz_frames", "fuzz_sensors", "parameter_variants", "seed_payloads"]


def fuzz_frames():
    """Small scans the seed payloads are encoded from: an off-grid room (a quarter of its
    returns), a 32-beam ring scan with a derived sensor (sent by id), 3 points and 1 point."""
    from lwbench.frame import Frame
    from lwbench.synthetic import check_frames

    frames = check_frames()
    room = frames["room"].subset(np.arange(0, len(frames["room"]), 4))
    ring = frames["hdl32-ring"].subset(np.arange(0, len(frames["hdl32-ring"]), 3))
    three = Frame(np.array([[1.0, 2.0, 0.5], [2.0, -1.0, 0.2], [-3.0, 0.5, -0.4]], np.float32), room.sensor)
    one = Frame(np.array([[4.0, 1.0, 0.3]], np.float32), room.sensor)
    return [room, ring, three, one]


#: Tables the seed payloads' encoders named (a derived grid, a sensor=derived variant), by id.
_ENCODED_SENSORS: dict[str, dict] = {}


def fuzz_sensors() -> list[dict]:
    """The full tables of :func:`fuzz_frames`' sensors and of every sensor a seed payload's
    encoder named: what a decode server is told, since seed payloads name their (derived)
    sensors by id -- a case naming one the server was not told is refused before any of the
    decoder's own code runs, which fuzzes nothing."""
    frames = {f.sensor.sensor_id: f.sensor.to_dict(full=True) for f in fuzz_frames()}
    return list({**frames, **_ENCODED_SENSORS}.values())


def parameter_variants(codec_cls, params: dict) -> list[dict]:
    """The given parameters, and each declared choice / flag changed one at a time."""
    out = [dict(params)]
    for p in codec_cls.all_params():
        if p.name in params or p.name == "device":
            continue
        values = list(p.choices or ()) if p.choices else ([not p.default] if p.type == "bool" else [])
        out += [{**params, p.name: v} for v in values if v != p.default]
    return out


_SEEDS: dict[tuple, list[tuple[dict, bytes]]] = {}


def seed_payloads(codec_cls, params: dict | None = None, frames=None, limit: int = 24) -> list[tuple[dict, bytes]]:
    """Valid payloads to mutate: ``(decoder params, bytes)`` for the codec's parameter variants
    on :func:`fuzz_frames` (variants it refuses are skipped). Cached per process for the
    default frames (encoding the seeds is most of a short campaign's cost)."""
    key = (class_ref(codec_cls), json.dumps(params or {}, sort_keys=True, default=str), limit)
    if frames is None and key in _SEEDS:
        return _SEEDS[key]
    out = _encode_seeds(codec_cls, params, fuzz_frames() if frames is None else frames, limit)
    if frames is None:
        _SEEDS[key] = out
    return out


def _encode_seeds(codec_cls, params: dict | None, frames, limit: int) -> list[tuple[dict, bytes]]:
    out = []
    for variant in parameter_variants(codec_cls, dict(params or {})):
        for frame in frames:
            encoder = codec_cls(**variant)
            try:
                out.append((variant, encoder.encode(frame)))
            except Exception:  # noqa: BLE001, S112 - a variant a scan does not support
                continue
            _ENCODED_SENSORS.update({s.sensor_id: s.to_dict(full=True) for s in encoder.sensors})
    rng = random.Random(0)
    rng.shuffle(out)
    return out[:limit]


@dataclass
class FuzzReport:
    codec: str
    cases: int = 0
    outcomes: Counter = field(default_factory=Counter)
    verdicts: Counter = field(default_factory=Counter)
    max_cpu_s: float = 0.0
    max_peak_mb: float = 0.0
    seconds: float = 0.0
    failures: list[tuple[str, str, bytes]] = field(default_factory=list)

    @property
    def payload_errors(self) -> int:
        return self.outcomes["PayloadError"]

    @property
    def other(self) -> int:
        """Cases that broke the contract (any escape but PayloadError, over time or memory)."""
        return self.cases - self.verdicts["fine"]

    def add(self, outcome: Outcome, case: bytes, keep: int = 20) -> None:
        self.cases += 1
        self.outcomes[outcome.kind] += 1
        self.verdicts[outcome.verdict] += 1
        self.max_cpu_s = max(self.max_cpu_s, outcome.cpu_s)
        self.max_peak_mb = max(self.max_peak_mb, outcome.peak_mb)
        if outcome.verdict != "fine" and len(self.failures) < keep:
            self.failures.append((outcome.verdict, outcome.message, case))

    def summary(self) -> str:
        bad = ", ".join(f"{k} {v}" for k, v in sorted(self.verdicts.items()) if k != "fine") or "none"
        return (f"{self.codec}: {self.cases} cases, {self.outcomes['ok']} decoded, {self.payload_errors} "
                f"PayloadError, other {self.other} ({bad}); max {self.max_cpu_s:.2f} s CPU, "
                f"{self.max_peak_mb:.0f} MB peak")


def fuzz_codec(codec_cls, params: dict | None = None, *, cases: int = 1000, seconds: float | None = None,
               seed: int = 0, server: DecodeServer | None = None, seeds=None,
               on_case: Callable[[int], None] | None = None) -> FuzzReport:
    """A campaign against one codec: ``cases`` mutated payloads (fewer if ``seconds`` runs out),
    decoded in a :class:`DecodeServer`; returns the counts. ``on_case(done)`` is called after
    each case (a progress bar)."""
    seeds = seed_payloads(codec_cls, params) if seeds is None else seeds
    report = FuzzReport(codec_cls.name)
    if not seeds:
        return report
    own = server is None
    server = server or DecodeServer()
    server.register_sensors(fuzz_sensors())
    ref = class_ref(codec_cls)
    bodies = [split_payload(data).body for _, data in seeds]
    ch = RandomChooser([seed, zlib.crc32(codec_cls.name.encode())])
    t0 = time.perf_counter()
    try:
        for i in range(cases):
            if seconds is not None and time.perf_counter() - t0 > seconds:
                break
            variant, data = seeds[i % len(seeds)]
            case = mutate(data, ch, bodies)
            report.add(server.decode(ref, variant, case, warm_with=data), case)
            if on_case is not None:
                on_case(i + 1)
    finally:
        if own:
            server.close()
    report.seconds = time.perf_counter() - t0
    return report
