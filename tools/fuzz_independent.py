"""An independent fuzz campaign: its own structure-aware mutator, not :mod:`lwbench.fuzz`'s.

    python tools/fuzz_independent.py [--cases 2000] [--seed 1] [--out DIR] [--corpus DIR] [CODEC ...]

Why a second fuzzer: a harness tested only against the mutations its authors thought of finds
only those bugs. This one shares nothing with ``lwbench.fuzz.mutate`` -- it parses the payload
container itself (magic, version, flags, codec id, metadata JSON, pose, body, CRC), mutates it
as a structure and re-seals the CRC:

- **header**: version / flags / id length / metadata length / body length fields rewritten,
  the container truncated or extended;
- **metadata**: the JSON parsed, one leaf (found by walking the tree) replaced by a hostile value
  (0, -1, 2^31, 2^63-1, 1e30, -1e30, 1e-300, "", [], {}, null, true, a long string), a key
  dropped or added, a number nudged (+-1, x2, /2, negated), a sensor description replaced by a
  hostile one (256 beams, 0.01 deg steps, 10 km and 1e30 m ranges, elevations of +-90, min
  range above max);
- **compressed sections**: a zstd frame found in the body inflated, its content mutated the
  same ways and compressed again (the codec's own sections, past the decompressor's checks);
- **body**: typed fields (u8/u16/u32/u64/f16/f32/f64) at an offset in the first 64 bytes or
  anywhere set to boundary values (0, 1, 2^8/16/24/31/32-1, 3.4e38, 1e30, NaN, inf, 1e-30),
  a run of float32 coordinates scaled by 1e6..1e30, bit flips, byte runs, truncation, extension,
  a splice with another seed's body.

Seeds are the codecs' payloads on the kit's scans (lwbench.testing: room, tunnel, cylinder,
32-beam ring, subsampled) and on tiny scans. Each case decodes in a sandboxed child
(lwbench.sandbox: one thread, RLIMIT_DATA 2 GB above its warm size, 5 s wall per case); the
verdict is judged here, by this tool's own rules:

- ``PayloadError`` or a cloud within reach: fine -- within reach = no point farther than 10 km,
  nor (for a codec whose valid payloads name their sensor) than that sensor's max range +50 %,
  or than a reach the header declares (``reach_m``, rangeimage) +50 %;
- anything else is counted: another exception type, ``absurd`` (a cloud beyond reach), ``bad
  output`` (not a finite float32 (M, 3)), ``over 1 s`` CPU, ``memory``, ``timeout``, ``crash``.

``--out DIR`` writes every failing case (``CODEC-N-VERDICT.lwb``); ``--corpus DIR`` writes the
same cases as regression inputs (tests/corpus/, replayed by tests/test_fuzz_corpus.py).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import struct
import sys
import time
import zlib
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAGIC = b"LWBP"
CPU_LIMIT_S = 1.0
WALL_LIMIT_S = 5.0
CEILING_MB = 2048
MAX_COORDINATE_M = 10_000.0  # no LiDAR return is 10 km away (this tool's own constant)
MARGIN = 0.5  # a decoded point may lie this share past its sensor's max range
SEEDS_PER_CODEC = 16


# -- the container, parsed independently -----------------------------------------------------------
@dataclass
class Container:
    version: int
    flags: int
    codec_id: bytes
    meta: bytes
    pose: bytes  # 24 bytes when flags & 1, else b""
    body: bytes

    @classmethod
    def parse(cls, data: bytes) -> Container:
        if data[:4] != MAGIC:
            raise ValueError("not a payload")
        version, flags, id_len = data[4], data[5], data[6]
        off = 7
        cid = data[off : off + id_len]
        off += id_len
        (meta_len,) = struct.unpack_from("<H", data, off)
        off += 2
        meta = data[off : off + meta_len]
        off += meta_len
        pose = b""
        if flags & 1:
            pose = data[off : off + 24]
            off += 24
        (body_len,) = struct.unpack_from("<I", data, off)
        off += 4
        body = data[off : off + body_len]
        return cls(version, flags, cid, meta, pose, body)

    def seal(self, *, id_len: int | None = None, meta_len: int | None = None, body_len: int | None = None) -> bytes:
        """The container's bytes with a valid CRC (length fields overridable: lies about lengths)."""
        out = bytearray(MAGIC)
        out += bytes(
            [self.version & 0xFF, self.flags & 0xFF, (len(self.codec_id) if id_len is None else id_len) & 0xFF]
        )
        out += self.codec_id
        out += struct.pack("<H", (len(self.meta) if meta_len is None else meta_len) & 0xFFFF) + self.meta
        out += self.pose
        out += struct.pack("<I", (len(self.body) if body_len is None else body_len) & 0xFFFFFFFF) + self.body
        return bytes(out) + struct.pack("<I", zlib.crc32(bytes(out)))


def reseal(raw: bytes) -> bytes:
    """Any bytes with a valid CRC appended over them (the checksum of a crafted payload)."""
    return raw + struct.pack("<I", zlib.crc32(raw))


# -- the mutator -----------------------------------------------------------------------------------
HOSTILE_JSON = [
    0,
    -1,
    1,
    2**31,
    2**32 - 1,
    2**63 - 1,
    -(2**63),
    1e30,
    -1e30,
    1e-300,
    0.5,
    255,
    65536,
    "",
    "x" * 300,
    [],
    {},
    None,
    True,
    False,
    [1e30, 1e30, 1e30],
    {"preset": "vlp16"},
]
HOSTILE_SENSORS = [
    {"beams": 256, "elevations": [-90.0 + 0.7 * i for i in range(256)], "azimuth_step": 0.01, "max_range": 10_000.0},
    {"beams": 2, "elevations": [90.0, -90.0], "azimuth_step": 0.01, "max_range": 1e30},
    {"beams": 1, "elevations": [0.0], "azimuth_step": 360.0, "max_range": 10_000.0, "min_range": 20_000.0},
    {"preset": "vlp16", "max_range": 10_000.0},
    {"preset": "os1-128"},
    {"preset": "hdl64e", "azimuth_step": 0.01},
    {"beams": 4, "elevations": [0, 0, 0, 0], "azimuth_step": 1e-9, "max_range": 50.0},
]
U_VALUES = [0, 1, 2, 3, 0x7F, 0xFF, 0x100, 0xFFFF, 0x10000, 1 << 24, (1 << 31) - 1, 1 << 31, (1 << 32) - 1]
F_VALUES = [
    0.0,
    -0.0,
    1e-30,
    -1e-30,
    1.0,
    -1.0,
    1e6,
    1e30,
    -1e30,
    3.4e38,
    -3.4e38,
    float("nan"),
    float("inf"),
    float("-inf"),
    65504.0,
]
FIELDS = {
    "u8": ("<B", 1),
    "u16": ("<H", 2),
    "u32": ("<I", 4),
    "u64": ("<Q", 8),
    "f16": ("<e", 2),
    "f32": ("<f", 4),
    "f64": ("<d", 8),
}


def _leaves(obj, path=()):
    """Every path to a value of a JSON tree (containers included: they may be replaced whole)."""
    yield path
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:64]):
            yield from _leaves(v, (*path, i))


def _set(obj, path, value):
    if not path:
        return value
    target = obj
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return obj


def _field_value(rng: random.Random, kind: str) -> bytes:
    fmt, size = FIELDS[kind]
    if kind.startswith("f"):
        value = rng.choice(F_VALUES)
        if kind == "f16" and abs(value) > 65504 and np.isfinite(value):
            value = 65504.0 * np.sign(value)
        return struct.pack(fmt, value)
    value = rng.choice(U_VALUES + [rng.getrandbits(8 * size)])
    return struct.pack(fmt, value & ((1 << (8 * size)) - 1))


def mutate_meta(c: Container, rng: random.Random) -> Container:
    try:
        meta = json.loads(c.meta.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        meta = {}
    if not isinstance(meta, dict):
        meta = {}
    op = rng.randrange(6)
    paths = list(_leaves(meta))
    if op == 0 and len(paths) > 1:  # one value replaced
        path = rng.choice(paths[1:])
        meta = _set(meta, path, rng.choice(HOSTILE_JSON))
    elif op == 1 and meta:  # a key dropped
        meta.pop(rng.choice(list(meta)))
    elif op == 2:  # a key added
        meta[rng.choice(["n", "count", "bits", "sensor", "grid", "extra", "shape", "bounds"])] = rng.choice(
            HOSTILE_JSON
        )
    elif op == 3:  # a hostile sensor
        meta["sensor"] = dict(rng.choice(HOSTILE_SENSORS))
    elif op == 4:  # a number nudged: small lies survive the sanity checks and reach deeper code
        numeric = [p for p in paths[1:] if _is_number(_get(meta, p))]
        if numeric:
            p = rng.choice(numeric)
            v = _get(meta, p)
            nudged = rng.choice([v + 1, v - 1, v * 2, v // 2 if isinstance(v, int) else v / 2, -v])
            meta = _set(meta, p, nudged)
    else:  # a number scaled
        numeric = [
            p for p in paths[1:] if isinstance(_get(meta, p), (int, float)) and not isinstance(_get(meta, p), bool)
        ]
        if numeric:
            p = rng.choice(numeric)
            v = _get(meta, p)
            meta = _set(meta, p, type(v)(v * rng.choice([0, -1, 1000, 10**6, 10**9])) if v else rng.choice(U_VALUES))
    raw = json.dumps(meta, separators=(",", ":")).encode()
    if len(raw) <= 0xFFFF:
        c.meta = raw
    return c


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _get(obj, path):
    for key in path:
        obj = obj[key]
    return obj


ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


def mutate_inside_zstd(body: bytes, rng: random.Random) -> bytes | None:
    """A zstd frame inside the body inflated, its content mutated (typed field, bit flips, a
    truncation or an extension) and compressed again: the codec's own sections, past the
    decompressor's checks. ``None`` when the body holds no frame that inflates."""
    import zstandard

    starts = [i for i in range(len(body)) if body.startswith(ZSTD_MAGIC, i)][:8]
    if not starts:
        return None
    off = rng.choice(starts)
    try:
        dobj = zstandard.ZstdDecompressor().decompressobj()
        inner = bytearray(dobj.decompress(body[off:]))
        rest = dobj.unused_data
    except zstandard.ZstdError:
        return None
    if len(inner) > 1 << 26:
        return None
    op = rng.randrange(4)
    if op == 0 and inner:
        kind = rng.choice(list(FIELDS))
        size = FIELDS[kind][1]
        at = rng.randrange(max(1, len(inner) - size + 1))
        inner[at : at + size] = _field_value(rng, kind)
    elif op == 1 and inner:
        for _ in range(rng.randint(1, 16)):
            i = rng.randrange(len(inner))
            inner[i] ^= 1 << rng.randrange(8)
    elif op == 2:
        inner = inner[: rng.randrange(len(inner) + 1)]
    else:
        inner += bytes(rng.choice([1, 4, 12, 1000]))
    return body[:off] + zstandard.ZstdCompressor(level=1).compress(bytes(inner)) + rest


def mutate_body(c: Container, rng: random.Random, bodies: list[bytes]) -> Container:
    body = bytearray(c.body)
    op = rng.randrange(11)
    if op >= 9:  # inside a compressed section
        inner = mutate_inside_zstd(bytes(body), rng)
        if inner is not None:
            c.body = inner
            return c
        op = rng.randrange(9)
    if op <= 2 and body:  # a typed field at a header-ish offset (op 0, 1) or anywhere (op 2)
        kind = rng.choice(list(FIELDS))
        size = FIELDS[kind][1]
        span = min(len(body), 64) if op < 2 else len(body)
        off = rng.randrange(max(1, span - size + 1))
        body[off : off + size] = _field_value(rng, kind)
    elif op == 3 and len(body) >= 16:  # a run of float32 coordinates scaled far away
        start = rng.randrange(0, len(body) - 12, 4) if len(body) > 16 else 0
        n = rng.choice([3, 12, 48, len(body) // 4])
        chunk = bytes(body[start : start + 4 * n])
        with np.errstate(over="ignore", invalid="ignore"):
            vals = np.frombuffer(chunk[: len(chunk) // 4 * 4], dtype="<f4").astype(np.float64)
            scaled = (vals * rng.choice([1e6, 1e12, 1e30]) + rng.choice([0.0, 1e5])).astype("<f4")
        body[start : start + len(scaled) * 4] = scaled.tobytes()
    elif op == 4 and body:  # bit flips
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(len(body))
            body[i] ^= 1 << rng.randrange(8)
    elif op == 5 and body:  # a byte run
        i = rng.randrange(len(body))
        body[i : i + rng.randint(1, 32)] = bytes([rng.choice([0, 0xFF, 0x7F, 0x80])]) * rng.randint(1, 32)
    elif op == 6:  # truncated
        body = body[: rng.randrange(len(body) + 1)]
    elif op == 7:  # extended
        body += (
            rng.choice([b"\0", b"\xff"]) * rng.choice([1, 3, 4, 12, 4096])
            if rng.random() < 0.5
            else os.urandom(rng.randint(1, 64))
        )
    else:  # a splice with another seed's body (same codec)
        other = rng.choice(bodies)
        cut_a, cut_b = rng.randrange(len(body) + 1), rng.randrange(len(other) + 1)
        body = body[:cut_a] + other[cut_b:]
    c.body = bytes(body)
    return c


def mutate_header(c: Container, rng: random.Random) -> bytes:
    op = rng.randrange(6)
    if op == 0:
        c.version = rng.choice([0, 2, 255])
        return c.seal()
    if op == 1:
        c.flags = rng.choice([1, 2, 0x80, 0xFF]) if not c.flags else 0
        return c.seal()
    if op == 2:
        return c.seal(meta_len=rng.choice([0, len(c.meta) + 1, max(0, len(c.meta) - 1), 0xFFFF]))
    if op == 3:
        return c.seal(body_len=rng.choice([0, len(c.body) + 1, max(0, len(c.body) - 1), 0xFFFFFFFF]))
    if op == 4:
        return c.seal(id_len=rng.choice([0, len(c.codec_id) + 1, 255]))
    sealed = c.seal()[:-4]
    return reseal(sealed[: rng.randrange(len(sealed) + 1)])


def mutate(data: bytes, rng: random.Random, bodies: list[bytes]) -> bytes:
    """One hostile case made from a valid payload, CRC re-sealed."""
    c = Container.parse(data)
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        which = rng.random()
        if which < 0.12:
            return mutate_header(c, rng)
        c = mutate_meta(c, rng) if which < 0.4 else mutate_body(c, rng, bodies)
    return c.seal()


# -- the decoding child (lwbench.sandbox) ----------------------------------------------------------
def _child(conn, parent: int, ceiling_mb: int, sensors: list[dict]) -> None:
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    from lwbench.sandbox import cap_memory, enter_child

    enter_child(parent)
    import torch

    from lwbench.errors import PayloadError
    from lwbench.payload import Payload
    from lwbench.registry import get_registry
    from lwbench.sensors.catalog import SensorCatalog
    from lwbench.sensors.model import SensorModel

    torch.set_num_threads(1)
    reg = get_registry()
    catalog = SensorCatalog()
    catalog.update(SensorModel.from_dict(d) for d in sensors)
    cap_memory(ceiling_mb)
    conn.send(("ready",))
    while True:
        msg = conn.recv()
        if msg is None:
            return
        name, params, data, seed_range = msg
        codec = reg.codec(name)(**params).use_sensors(list(catalog))
        t0 = time.process_time()
        try:
            out = codec.decode(data)
            cpu = time.process_time() - t0
            kind, message = _judge(out, data, seed_range, catalog, Payload, SensorModel)
        except PayloadError as exc:
            cpu = time.process_time() - t0
            memory = "can't allocate" in str(exc) or isinstance(exc.__context__, MemoryError)
            kind, message = ("memory" if memory else "PayloadError"), str(exc)[:200]
        except MemoryError as exc:
            cpu, kind, message = time.process_time() - t0, "memory", str(exc)[:200]
        except BaseException as exc:  # noqa: BLE001 - counting escapes is the point
            cpu, kind, message = time.process_time() - t0, type(exc).__name__, str(exc)[:200]
        conn.send((kind, cpu, message))


def _judge(out, data, seed_range, catalog, Payload, SensorModel) -> tuple[str, str]:  # noqa: N803
    if not (
        isinstance(out, np.ndarray)
        and out.ndim == 2
        and out.shape[1] == 3
        and out.dtype == np.float32
        and np.isfinite(out).all()
    ):
        return "bad output", f"{type(out).__name__} {getattr(out, 'shape', '')} {getattr(out, 'dtype', '')}"
    if not len(out):
        return "ok", ""
    reach = MAX_COORDINATE_M
    if seed_range is not None:  # the codec's payloads name their sensor: the case's own, if it resolves
        reach = min(reach, seed_range * (1 + MARGIN))
        try:
            wire = Payload.from_bytes(data).meta.get("sensor")
            own = SensorModel.from_wire(wire, catalog) if isinstance(wire, dict) else None
            if own is not None:
                reach = min(MAX_COORDINATE_M, own.max_range * (1 + MARGIN))
            declared = Payload.from_bytes(data).meta.get("reach_m")  # a header's own bound (rangeimage)
            if isinstance(declared, (int, float)) and not isinstance(declared, bool) and declared > 0:
                reach = min(MAX_COORDINATE_M, max(reach, float(declared) * (1 + MARGIN)))
        except Exception:  # noqa: BLE001, S110 - a sensor the case cannot name: the seed's reach
            pass
    dist = np.linalg.norm(out.astype(np.float64), axis=1)
    far = int((dist > reach).sum())
    if far:
        return "absurd", f"{far} of {len(out)} points beyond {reach:g} m (max {dist.max():.3g} m)"
    return "ok", ""


class Decoder:
    """The parent's side: one sandboxed child, restarted after a timeout or a crash."""

    def __init__(self, sensors: list[dict]) -> None:
        self.sensors = sensors
        self.box = None

    def _start(self) -> None:
        from lwbench.sandbox import Sandbox

        self.box = Sandbox(_child, (CEILING_MB, self.sensors), name="lwbench-fuzz-independent")
        self.box.start(300.0, "the independent fuzzer's decoder")

    def decode(self, name: str, params: dict, data: bytes, seed_range: float | None) -> tuple[str, float, str]:
        if self.box is None or not self.box.alive:
            self._start()
        got = self.box.call((name, params, data, seed_range), WALL_LIMIT_S)
        if isinstance(got, tuple):
            return got
        code = self.box.kill()
        self.box = None
        if got == "timeout":
            return "timeout", WALL_LIMIT_S, f"no answer within {WALL_LIMIT_S:g} s"
        return "crash", 0.0, f"exit code {code}"

    def warm(self, name: str, params: dict, data: bytes) -> None:
        if self.box is None or not self.box.alive:
            self._start()
        if self.box.call((name, params, data, None), 300.0) in ("timeout", "died"):
            self.box.kill()
            self.box = None

    def close(self) -> None:
        if self.box is not None:
            self.box.stop()


# -- seeds and the campaign ------------------------------------------------------------------------
def seed_frames():
    """The kit's scans (its check frames, a tunnel, half a cylinder), subsampled (cases stay small
    and decodes quick), and two tiny scans."""
    from lwbench import Frame
    from lwbench.testing import check_frames, cylinder_scan, tunnel_scan

    out = []
    scans = {**check_frames(), "tunnel": tunnel_scan(seed=3), "cylinder": cylinder_scan(half=True)}
    for i, (label, frame) in enumerate(sorted(scans.items())):
        step = max(1, len(frame) // 3000)
        out.append((label, frame.subset(np.arange(i % step, len(frame), step))))
    base = out[0][1]
    out.append(("two", Frame(np.array([[3.0, 1.0, 0.2], [-2.0, 4.0, -0.5]], np.float32), base.sensor)))
    out.append(("one", Frame(np.array([[5.0, 0.0, 0.0]], np.float32), base.sensor)))
    return out


def variants(cls, base: dict) -> list[dict]:
    """The base parameters and each declared choice / flag changed one at a time (every body
    layout a codec can write: rangeimage's image bodies, the serializer's quantized points ...)."""
    out = [dict(base)]
    for p in cls.all_params():
        if p.name in base or p.name == "device":
            continue
        values = [c for c in (p.choices or ()) if c != p.default] or ([not p.default] if p.type == "bool" else [])
        out += [{**base, p.name: v} for v in values]
    return out


def seeds_for(name: str, cls, frames) -> tuple[list[tuple[dict, bytes, float | None]], list]:
    """Up to SEEDS_PER_CODEC valid payloads ``(params, bytes, the scan's max range when the
    payload names its sensor)``, and the sensors the encoders named (the decoder must know them)."""
    out, sensors = [], []
    for params in variants(cls, cls.test_params()):
        for _, frame in frames:
            encoder = cls(**params)
            try:
                data = encoder.encode(frame)
            except Exception:  # noqa: BLE001, S112 - a scan this codec refuses
                continue
            sensors += [frame.sensor, *encoder.sensors]
            names_sensor = b'"sensor"' in Container.parse(data).meta
            out.append((params, data, float(frame.sensor.max_range) if names_sensor else None))
    random.Random(name).shuffle(out)
    return out[:SEEDS_PER_CODEC], sensors


@dataclass
class Tally:
    codec: str
    cases: int = 0
    kinds: Counter = field(default_factory=Counter)
    over_cpu: int = 0
    max_cpu: float = 0.0
    failures: list[tuple[str, str, bytes]] = field(default_factory=list)

    def add(self, kind: str, cpu: float, message: str, case: bytes) -> None:
        self.cases += 1
        self.kinds[kind] += 1
        self.max_cpu = max(self.max_cpu, cpu)
        slow = kind in ("ok", "PayloadError") and cpu > CPU_LIMIT_S
        self.over_cpu += slow
        if kind not in ("ok", "PayloadError") or slow:
            self.failures.append(("over_1s" if slow else kind.replace(" ", "_"), message, case))

    @property
    def escapes(self) -> int:
        return sum(v for k, v in self.kinds.items() if k not in ("ok", "PayloadError", "absurd"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("codecs", nargs="*")
    ap.add_argument("--cases", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--corpus", type=Path, help="write each failing case here as a regression input")
    args = ap.parse_args()
    from lwbench.registry import get_registry

    reg = get_registry()
    names = args.codecs or sorted(n for n, c in reg.codecs.items() if not c.needs)
    frames = seed_frames()
    seeds, known = {}, {}
    for name in names:
        seeds[name], named = seeds_for(name, reg.codec(name), frames)
        known.update({s.sensor_id: s for s in named})
    decoder = Decoder([s.to_dict(full=True) for s in known.values()])
    tallies = []
    try:
        for name in names:
            t0 = time.perf_counter()
            tally = Tally(name)
            own = seeds[name]
            if own:
                for params, data, _ in own:  # imports and first calls of every variant, unmeasured
                    decoder.warm(name, params, data)
                rng = random.Random(f"{args.seed}:{name}")
                bodies = [Container.parse(d).body for _, d, _ in own]
                for i in range(args.cases):
                    params, data, seed_range = own[i % len(own)]
                    case = mutate(data, rng, bodies)
                    tally.add(*decoder.decode(name, params, case, seed_range), case)
            tallies.append(tally)
            worst = ", ".join(f"{k} {v}" for k, v in sorted(tally.kinds.items()) if k not in ("ok", "PayloadError"))
            print(
                f"{name}: {tally.cases} cases, {len(own)} seeds, {tally.kinds['ok']} decoded, "
                f"{tally.kinds['PayloadError']} PayloadError, absurd {tally.kinds['absurd']}, escapes "
                f"{tally.escapes}, over 1 s {tally.over_cpu} ({worst or 'none'}); max {tally.max_cpu:.2f} s CPU, "
                f"{time.perf_counter() - t0:.0f} s",
                flush=True,
            )
            for folder in (args.out, args.corpus):
                if folder and tally.failures:
                    folder.mkdir(parents=True, exist_ok=True)
                    for i, (verdict, _, case) in enumerate(tally.failures[:40]):
                        (folder / f"{name}-{i}-{verdict}.lwb").write_bytes(case)
            for verdict, message, _ in tally.failures[:6]:
                print(f"    {verdict}: {message}", flush=True)
    finally:
        decoder.close()
    print("\n| codec | cases | decoded | PayloadError | non-PayloadError | absurd | over 1 s CPU | max CPU s |")
    print("|---|---|---|---|---|---|---|---|")
    for t in tallies:
        print(
            f"| {t.codec} | {t.cases} | {t.kinds['ok']} | {t.kinds['PayloadError']} | {t.escapes} | "
            f"{t.kinds['absurd']} | {t.over_cpu} | {t.max_cpu:.2f} |"
        )
    sys.exit(0)


if __name__ == "__main__":
    main()
