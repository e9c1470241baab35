"""Crafted payloads: valid ones changed field by field, with a valid CRC (the fuzzer's mutator).

:func:`mutate` turns a valid payload into a hostile one -- metadata values replaced by 5,000-digit
integers, deep nesting, NaN, hostile sensor tables; body bits flipped, counts overwritten with
interesting values, truncated, extended, zstd frames that declare 2 GiB; raw header fields
changed -- and always re-seals it with a valid CRC. Its choices come from a :class:`Chooser`, so a
seeded ``random.Random`` (:class:`RandomChooser`), hypothesis' ``data`` (tests/test_fuzz.py, which
then shrinks a failure to a small case) or atheris' data provider (tools/fuzz_atheris.py) drive it.
"""

from __future__ import annotations

import json
import random
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

__all__ = ["MAX_CASE_BYTES", "Chooser", "RandomChooser", "assemble", "mutate", "split_payload"]

MAX_CASE_BYTES = 1 << 20  # inputs of at most 1 MB

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


def split_payload(data: bytes) -> _Parts:
    """A payload's sections, parsed (the CRC checked): what :func:`mutate` changes."""
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
    parts = split_payload(seed)
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
