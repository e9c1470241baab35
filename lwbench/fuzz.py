"""Fuzzing decoders: crafted payloads against a codec, decoded out of process, bounded.

The CRC catches accidents; a crafted payload (fields changed, CRC recomputed) reaches codec
code. This module makes such payloads from real ones and checks the contract every decoder
keeps (DESIGN.md, "Payloads"): **only** :class:`~lwbench.PayloadError` escapes, and no decode
of an input of at most 1 MB takes more than a second of CPU or 512 MB of memory.

- :func:`mutate` turns a valid payload into a hostile one -- metadata values replaced by
  5,000-digit integers, deep nesting, NaN, hostile sensor tables; body bits flipped, counts
  overwritten with interesting values, truncated, extended, zstd frames that declare 2 GiB;
  raw header fields changed -- and always re-seals it with a valid CRC. Its choices come from a
  :class:`Chooser`, so a seeded ``random.Random`` (:class:`RandomChooser`), hypothesis' ``data``
  (tests/test_fuzz.py, which then shrinks a failure to a small case) or atheris' data provider
  (tools/fuzz_atheris.py) can drive it.
- :class:`DecodeServer` decodes in a child process with one thread, a memory ceiling
  (``RLIMIT_DATA``: a bomb becomes a ``MemoryError`` instead of eating the machine) and a
  generous per-case wall-clock timeout (the child is killed and replaced), and measures each
  case's CPU time and peak memory (``VmHWM``, reset per case).
- :func:`fuzz_codec` is a whole campaign: seed payloads encoded from small scans with the
  codec's declared parameter choices, then mutated cases until a count or a time budget; its
  :class:`FuzzReport` counts outcomes (``ok``, ``PayloadError`` and everything else).
"""

from __future__ import annotations

import importlib
import json
import os
import random
import re
import struct
import time
import zlib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing import get_context
from typing import Any, Protocol

import numpy as np

__all__ = [
    "Chooser",
    "RandomChooser",
    "DecodeServer",
    "Outcome",
    "FuzzReport",
    "assemble",
    "mutate",
    "seed_payloads",
    "fuzz_codec",
    "fuzz_sensors",
    "class_ref",
    "shared_server",
    "MAX_CASE_BYTES",
    "CPU_LIMIT_S",
    "MEMORY_LIMIT_MB",
]

MAX_CASE_BYTES = 1 << 20  # inputs of at most 1 MB
CPU_LIMIT_S = 1.0  # no decode over a second of CPU ...
MEMORY_LIMIT_MB = 512  # ... or 512 MB above what the process held before it
_TIMEOUT_S = 20.0  # wall clock per case before the child is killed (generous: a shared machine)
_CEILING_MB = 1536  # RLIMIT_DATA above the warm child: a bomb fails instead of swapping

_U32 = (0, 1, 2, 3, 7, 255, 256, 4095, 65535, 65536, 1 << 20, 1 << 24, 1 << 26, (1 << 31) - 1, 1 << 31,
        (1 << 32) - 1)
_F32 = (0.0, -0.0, 1e-45, -1.0, 1e-30, 1e30, 3.4e38, float("inf"), float("-inf"), float("nan"))
_JSON = (
    "0", "-1", "1", "2", "255", "65536", "4294967296", "9223372036854775807", "-9223372036854775808",
    "9" * 5000, "1e308", "-1e308", "1e-320", "NaN", "Infinity", "-Infinity", "null", "true", "false",
    '""', '"x"', '"' + "A" * 2000 + '"', "[]", "{}", "[1,2,3]", '{"a":1}', "[" * 5000 + "]" * 5000,
    '{"a":' * 2000 + "1" + "}" * 2000, "0.5", "1.5", "-0.0", "3.4e38",
)
_SENSORS = (
    '{"preset":5}', '{"preset":"nope"}', '{"preset":null}', '{"preset":["vlp16"]}', '{"id":"0123456789abcdef"}',
    '{"id":7}', '{"id":"x","preset":"vlp16"}', "[]", '"vlp16"', "{}",
    '{"name":"big","elevations_deg":[' + ",".join(f"{-40 + 80 * i / 3999:.4f}" for i in range(4000))
    + '],"azimuth_step_deg":0.01,"min_range":0.1,"max_range":100,"rate_hz":10}',
    '{"name":"wide","elevations_deg":[' + ",".join(f"{-40 + 80 * i / 255:.3f}" for i in range(256))
    + '],"azimuth_step_deg":0.01,"min_range":0.1,"max_range":100,"rate_hz":10}',
    '{"name":"dense","elevations_deg":[' + ",".join(f"{-20 + 40 * i / 127:.3f}" for i in range(128))
    + '],"azimuth_step_deg":0.05,"min_range":0.1,"max_range":100,"rate_hz":10}',
    '{"name":"nan","elevations_deg":[NaN,1.0],"azimuth_step_deg":1.0,"min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"fine","elevations_deg":[0.0],"azimuth_step_deg":1e-7,"min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"zero","elevations_deg":[0.0],"azimuth_step_deg":0,"min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"none","elevations_deg":[],"azimuth_step_deg":1,"min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"far","elevations_deg":[0.0],"azimuth_step_deg":1,"min_range":0.1,"max_range":1e300,"rate_hz":10}',
    '{"name":"inv","elevations_deg":[0.0],"azimuth_step_deg":1,"min_range":9,"max_range":1,"rate_hz":10}',
    '{"name":"str","elevations_deg":"abc","azimuth_step_deg":1,"min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"t","elevations_deg":[0.0],"azimuth_step_deg":"1","min_range":0.1,"max_range":10,"rate_hz":10}',
    '{"name":"big-int","elevations_deg":[' + "9" * 400 + '],"azimuth_step_deg":1,"min_range":0.1,'
    '"max_range":10,"rate_hz":10}',
)
_ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


class Chooser(Protocol):
    """Where a mutation's choices come from (a seeded RNG, hypothesis, atheris)."""

    def int(self, lo: int, hi: int) -> int: ...  # inclusive

    def bytes(self, n: int) -> bytes: ...


class RandomChooser:
    """Choices from a seeded ``random.Random``: a campaign is reproducible from its seed."""

    def __init__(self, seed: int | Sequence[int] = 0) -> None:
        self.rng = random.Random(repr(seed))

    def int(self, lo: int, hi: int) -> int:
        return self.rng.randint(lo, hi)

    def bytes(self, n: int) -> bytes:
        return self.rng.randbytes(n)


def _pick(ch: Chooser, seq: Sequence[Any]) -> Any:
    return seq[ch.int(0, len(seq) - 1)]


# -- building and mutating payloads ------------------------------------------------------------
def assemble(codec_id: bytes, meta: bytes, body: bytes, pose: bytes | None = None, *, version: int = 1,
             flags: int | None = None) -> bytes:
    """Payload bytes from raw sections -- any metadata bytes, not just valid JSON -- sealed with
    a valid CRC32 (what :meth:`lwbench.Payload.to_bytes` would refuse to write)."""
    meta = meta[:0xFFFF]
    flags = (1 if pose is not None else 0) if flags is None else flags
    blob = b"".join([
        b"LWBP", struct.pack("<BBB", version & 0xFF, flags & 0xFF, len(codec_id) & 0xFF), codec_id,
        struct.pack("<H", len(meta)), meta, pose or b"", struct.pack("<I", len(body)), body,
    ])
    return blob + struct.pack("<I", zlib.crc32(blob))


@dataclass
class _Parts:
    codec_id: bytes
    meta: dict
    body: bytes
    pose: bytes | None


def _split(data: bytes) -> _Parts:
    from lwbench.geometry import pose_to_vec
    from lwbench.payload import Payload

    p = Payload.from_bytes(data)
    pose = struct.pack("<6f", *pose_to_vec(p.pose)) if p.pose is not None else None
    return _Parts(p.codec_id.encode(), dict(p.meta), p.body, pose)


def _meta_paths(meta: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(meta, dict):
        for k, v in meta.items():
            out += _meta_paths(v, (*prefix, k))
    elif isinstance(meta, list) and meta:
        out += _meta_paths(meta[0], (*prefix, 0))
    return out


def _with_token(meta: dict, path: tuple, token: str) -> bytes:
    """The metadata as JSON with the value at ``path`` replaced by a raw JSON ``token``."""
    marker = "\x00LWBENCH-FUZZ\x00"
    meta = json.loads(json.dumps(meta))
    node = meta
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = marker
    return json.dumps(meta, separators=(",", ":")).replace(json.dumps(marker), token, 1).encode()


def _zstd_bomb(body: bytes) -> bytes:
    """``body`` with its first zstd frame replaced by one that declares 2 GiB of content."""
    import zstandard

    at = body.find(_ZSTD_MAGIC)
    if at < 0:
        return body
    frame = zstandard.ZstdCompressor(level=1, write_content_size=False, write_checksum=False).compress(
        b"\x00" * 65536
    )
    fhd, rest = frame[4], frame[5:]
    # Frame header descriptor: content-size field of 4 bytes (flag 2), the rest unchanged.
    bomb = _ZSTD_MAGIC + bytes([(fhd & 0x3F) | 0x80]) + rest[:1] + struct.pack("<I", 1 << 31) + rest[1:]
    return body[:at] + bomb


def _body_mutation(ch: Chooser, body: bytes, others: Sequence[bytes]) -> bytes:
    b = bytearray(body)
    kind = ch.int(0, 7)
    if kind == 0 and b:  # flip a few bits
        for _ in range(ch.int(1, 8)):
            b[ch.int(0, len(b) - 1)] ^= 1 << ch.int(0, 7)
    elif kind == 1 and b:  # overwrite bytes
        at = ch.int(0, len(b) - 1)
        chunk = ch.bytes(ch.int(1, 16))
        b[at : at + len(chunk)] = chunk
    elif kind == 2 and len(b) >= 4:  # an interesting integer where headers keep their counts
        at = ch.int(0, min(len(b) - 4, 48))
        fmt = _pick(ch, ("<I", "<H", "<B", "<i"))
        value = _pick(ch, _U32)
        value = value & 0xFF if fmt == "<B" else value & 0xFFFF if fmt == "<H" else value
        value = value - (1 << 32) if fmt == "<i" and value >= 1 << 31 else value
        struct.pack_into(fmt, b, at, value)
    elif kind == 3 and len(b) >= 4:  # an interesting float anywhere
        struct.pack_into("<f", b, ch.int(0, len(b) - 4), _pick(ch, _F32))
    elif kind == 4:  # truncate
        del b[ch.int(0, len(b)) :]
    elif kind == 5:  # extend
        n = ch.int(1, 1 << ch.int(0, 16))
        b += b"\x00" * n if ch.int(0, 1) else ch.bytes(min(n, 4096)) * (n // 4096 + 1)
    elif kind == 6:
        return _zstd_bomb(bytes(b))
    elif others:  # another payload's body under this header
        return _pick(ch, others)
    return bytes(b)


def mutate(seed: bytes, ch: Chooser, others: Sequence[bytes] = ()) -> bytes:
    """A hostile variant of the valid payload ``seed``, with a valid CRC, at most 1 MB.

    ``others`` are bodies of the codec's other seed payloads, for splices."""
    parts = _split(seed)
    meta_raw = json.dumps(parts.meta, separators=(",", ":")).encode()
    body, pose, cid, version, flags = parts.body, parts.pose, parts.codec_id, 1, None
    for _ in range(ch.int(1, 3)):
        kind = ch.int(0, 9)
        paths = _meta_paths(parts.meta)
        if kind == 0 and paths:  # one metadata value becomes an interesting token
            meta_raw = _with_token(parts.meta, _pick(ch, paths), _pick(ch, _JSON))
        elif kind == 1:  # a hostile sensor description
            meta_raw = _with_token({**parts.meta, "sensor": 0}, ("sensor",), _pick(ch, _SENSORS))
        elif kind == 2 and parts.meta:  # a field missing
            drop = _pick(ch, sorted(parts.meta))
            meta_raw = json.dumps({k: v for k, v in parts.meta.items() if k != drop}).encode()
        elif kind == 3:  # metadata that is not an object, or not JSON
            meta_raw = _pick(ch, [t.encode() for t in _JSON] + [ch.bytes(ch.int(0, 64))])
        elif kind in (4, 5, 6):
            body = _body_mutation(ch, body, others)
        elif kind == 7:  # the pose
            vals = [_pick(ch, _F32) if ch.int(0, 2) == 0 else 0.0 for _ in range(6)]
            pose = struct.pack("<6f", *vals)
        elif kind == 8:  # raw header fields
            which = ch.int(0, 3)
            if which == 0:
                version = _pick(ch, (0, 1, 2, 255))
            elif which == 1:
                flags = _pick(ch, (0, 1, 2, 3, 0x80, 0xFF))
            elif which == 2:
                cid = _pick(ch, (b"", cid + b"\x00", cid.upper(), b"\xff" * 3, cid[:-1]))
            else:
                pose = None if pose is not None else struct.pack("<6f", *[0.0] * 6)
        else:  # raw bytes of the sealed payload, then re-sealed
            raw = bytearray(assemble(cid, meta_raw, body, pose, version=version, flags=flags)[:-4])
            for _ in range(ch.int(1, 4)):
                raw[ch.int(4, len(raw) - 1)] = ch.int(0, 255)
            return _seal(bytes(raw))
    out = assemble(cid, meta_raw, body[: MAX_CASE_BYTES - len(meta_raw) - 64], pose, version=version, flags=flags)
    return out[:MAX_CASE_BYTES]


def _seal(raw: bytes) -> bytes:
    return raw + struct.pack("<I", zlib.crc32(raw))


# -- decoding out of process -------------------------------------------------------------------
@dataclass(frozen=True)
class Outcome:
    """What one decode did: ``kind`` is ``ok``, ``PayloadError``, an exception type's name,
    ``bad output``, ``memory`` (a ``MemoryError``, possibly wrapped), ``timeout`` or ``crash``."""

    kind: str
    cpu_s: float = 0.0
    peak_mb: float = 0.0
    message: str = ""

    @property
    def verdict(self) -> str:
        """``fine`` or what broke the contract (the kind, ``over 1 s`` or ``over 512 MB``)."""
        if self.kind not in ("ok", "PayloadError"):
            return self.kind
        if self.cpu_s > CPU_LIMIT_S:
            return "over 1 s"
        if self.peak_mb > MEMORY_LIMIT_MB:
            return "over 512 MB"
        return "fine"


def _status_mb(key: str) -> float:
    try:
        with open("/proc/self/status") as fh:
            m = re.search(rf"^{key}:\s+(\d+) kB", fh.read(), re.M)
        return int(m.group(1)) / 1024 if m else 0.0
    except OSError:
        return 0.0


def _reset_peak() -> None:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _memory_cause(exc: BaseException) -> bool:
    seen = exc
    while seen is not None:
        if isinstance(seen, MemoryError) or "can't allocate memory" in str(seen):
            return True
        seen = seen.__context__ or seen.__cause__
    return False


def _resolve(ref: str) -> type:
    module, _, qual = ref.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def class_ref(cls: type) -> str:
    """``module:qualname`` of a codec class, importable in a child process."""
    return f"{cls.__module__}:{cls.__qualname__}"


def _serve(conn, ceiling_mb: int) -> None:  # the child
    import resource

    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    import torch

    from lwbench.catalog import SensorCatalog
    from lwbench.errors import PayloadError
    from lwbench.sensor import SensorModel

    torch.set_num_threads(1)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a crash is counted, not dumped
    data_mb = _status_mb("VmData")
    if data_mb:  # the ceiling, set before any decode: a bomb fails instead of eating the machine
        ceiling = int((data_mb + ceiling_mb) * 2**20)
        resource.setrlimit(resource.RLIMIT_DATA, (ceiling, resource.getrlimit(resource.RLIMIT_DATA)[1]))
    classes: dict[str, type] = {}
    sensors = SensorCatalog()  # what the campaign says its payloads may name
    conn.send(("ready",))
    while True:
        msg = conn.recv()
        if msg is None:
            return
        op, *args = msg
        if op == "sensors":
            sensors.update(SensorModel.from_dict(d) for d in args[0])
            conn.send(("ok",))
            continue
        ref, params, data, warm = args
        cls = classes.get(ref) or classes.setdefault(ref, _resolve(ref))
        if warm:  # imports and first-call set-up, not measured
            try:
                cls(**params).use_sensors(sensors).decode(data)
            except Exception:  # noqa: BLE001, S110 - warm-up only
                pass
            conn.send(("ok",))
            continue
        _reset_peak()
        before = _status_mb("VmRSS")
        t0 = time.process_time()
        kind, message = "ok", ""
        try:
            out = cls(**params).use_sensors(sensors).decode(data)
            arr = np.asarray(out)
            if not (isinstance(out, np.ndarray) and arr.ndim == 2 and arr.shape[1] == 3
                    and arr.dtype == np.float32 and np.isfinite(arr).all()):
                kind, message = "bad output", f"{type(out).__name__} {getattr(arr, 'shape', '')} {arr.dtype}"
        except PayloadError as exc:
            kind, message = ("memory" if _memory_cause(exc) else "PayloadError"), str(exc)[:300]
        except BaseException as exc:  # noqa: BLE001 - the point of the harness
            kind = "memory" if _memory_cause(exc) else type(exc).__name__
            message = str(exc)[:300]
        cpu = time.process_time() - t0
        peak = max(0.0, _status_mb("VmHWM") - before)
        conn.send((kind, cpu, peak, message))


class DecodeServer:
    """A child process that decodes cases one at a time, replaced when it dies or hangs."""

    def __init__(self, *, timeout_s: float = _TIMEOUT_S, ceiling_mb: int = _CEILING_MB) -> None:
        self.timeout_s, self.ceiling_mb = timeout_s, ceiling_mb
        self._proc = self._conn = None
        self._sensors: list[dict] = []
        self._warm: set[tuple[str, str]] = set()
        self.restarts = 0

    def _start(self) -> None:
        ctx = get_context("spawn")
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, self.ceiling_mb), daemon=True, name="lwbench-fuzz")
        self._proc.start()
        child.close()
        self._conn = parent
        self._warm.clear()
        if not parent.poll(300.0):  # start-up (imports) is not a case's time
            raise RuntimeError("the fuzz decode server did not start within 300 s")
        parent.recv()
        if self._sensors:
            self._call(("sensors", self._sensors), 300.0)

    def _call(self, msg: tuple, timeout: float) -> tuple | str:
        """The child's answer, ``"timeout"`` or ``"died"``."""
        try:
            self._conn.send(msg)
            if not self._conn.poll(timeout):
                return "timeout"
            return self._conn.recv()
        except (EOFError, OSError):
            return "died"

    def register_sensors(self, sensors: Sequence[dict]) -> None:
        """Sensor tables the child must know (payloads name derived sensors by id)."""
        self._sensors = list(sensors)
        if self._proc is not None:
            self._call(("sensors", self._sensors), 120.0)

    def decode(self, ref: str, params: dict, data: bytes, warm_with: bytes | None = None) -> Outcome:
        if self._proc is None or not self._proc.is_alive():
            self._start()
        key = (ref, json.dumps(params, sort_keys=True, default=str))
        if warm_with is not None and key not in self._warm:
            # Imports and first-call set-up on a valid payload, unmeasured.
            if self._call(("decode", ref, params, warm_with, True), 300.0) == "died":
                self._kill()
                self._start()
            self._warm.add(key)
        got = self._call(("decode", ref, params, data, False), self.timeout_s)
        if isinstance(got, tuple):
            return Outcome(got[0], got[1], got[2], got[3])
        code = self._kill()
        if got == "timeout":
            return Outcome("timeout", self.timeout_s, 0.0, f"no answer within {self.timeout_s:g} s")
        return Outcome("crash", 0.0, 0.0, f"decoder process died (exit code {code})")

    def _kill(self) -> int | None:
        if self._proc.is_alive():
            self._proc.kill()
        self._proc.join(5)
        code = self._proc.exitcode
        self.restarts += 1
        self._proc = None
        return code

    def close(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            try:
                self._conn.send(None)
                self._proc.join(5)
            except (OSError, BrokenPipeError):
                pass
            if self._proc.is_alive():
                self._proc.kill()
                self._proc.join(5)
        self._proc = None

    def __enter__(self) -> DecodeServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# -- campaigns ---------------------------------------------------------------------------------
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


def fuzz_sensors() -> list[dict]:
    """The full tables of :func:`fuzz_frames`' sensors: what a decode server is told, since seed
    payloads name their (derived) sensors by id."""
    return [s.to_dict(full=True) for s in {f.sensor.sensor_id: f.sensor for f in fuzz_frames()}.values()]


def _variants(codec_cls, params: dict) -> list[dict]:
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
    for variant in _variants(codec_cls, dict(params or {})):
        for frame in frames:
            try:
                out.append((variant, codec_cls(**variant).encode(frame)))
            except Exception:  # noqa: BLE001, S112 - a variant a scan does not support
                continue
    rng = random.Random(0)
    rng.shuffle(out)
    return out[:limit]


_SHARED: DecodeServer | None = None


def shared_server() -> DecodeServer:
    """One decode server per process, closed at exit (the conformance kit's fuzz check and the
    tests share it, so the child's start-up -- imports -- is paid once)."""
    global _SHARED
    if _SHARED is None:
        import atexit

        _SHARED = DecodeServer()
        atexit.register(_SHARED.close)
    return _SHARED


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
               seed: int = 0, server: DecodeServer | None = None, seeds=None) -> FuzzReport:
    """A campaign against one codec: ``cases`` mutated payloads (fewer if ``seconds`` runs out),
    decoded in a :class:`DecodeServer`; returns the counts."""
    seeds = seed_payloads(codec_cls, params) if seeds is None else seeds
    report = FuzzReport(codec_cls.name)
    if not seeds:
        return report
    own = server is None
    server = server or DecodeServer()
    server.register_sensors(fuzz_sensors())
    ref = class_ref(codec_cls)
    bodies = [_split(data).body for _, data in seeds]
    ch = RandomChooser([seed, zlib.crc32(codec_cls.name.encode())])
    t0 = time.perf_counter()
    try:
        for i in range(cases):
            if seconds is not None and time.perf_counter() - t0 > seconds:
                break
            variant, data = seeds[i % len(seeds)]
            case = mutate(data, ch, bodies)
            report.add(server.decode(ref, variant, case, warm_with=data), case)
    finally:
        if own:
            server.close()
    report.seconds = time.perf_counter() - t0
    return report
