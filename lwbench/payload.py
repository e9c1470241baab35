"""The wire format: what crosses the link, byte for byte.

Layout (little endian)::

    magic      4 s   b"LWBP"
    version    u8    FORMAT_VERSION
    flags      u8    bit 0: a sensor pose follows the header
    id_len     u8    length of the codec id
    codec_id   id_len bytes, ASCII
    meta_len   u16   length of the metadata
    meta       meta_len bytes, UTF-8 JSON object: the parameters needed to decode
    [pose      6 x f32: translation x,y,z and rotation vector (axis * angle, rad)]
    body_len   u32
    body       body_len bytes, codec specific
    crc32      u32   over every byte before it

The metadata is JSON, not pickle, so decoding never executes code. Every malformed input --
truncated, bit-flipped, foreign, a future version -- raises :class:`PayloadError`.

A crafted payload (fields changed, CRC recomputed) passes the checksum, so the header is also
*bounded* here, before any codec sees it: metadata nested at most :data:`MAX_META_DEPTH` deep
(deeper JSON made ``json.loads`` raise ``RecursionError``), integers of at most 19 digits (a
5,000-digit ``bits`` raised ``ValueError`` when a codec converted it), finite floats only, no
unknown flag bits, a codec id of plain name characters and a finite, plausible pose.
Counts inside the body are the codecs' to check, with :func:`lwbench.limits.check_count`.
"""

from __future__ import annotations

import json
import math
import re
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.errors import PayloadError
from lwbench.geometry import pose_to_vec, vec_to_pose

__all__ = ["Payload", "PayloadError", "FORMAT_VERSION", "MAGIC", "MAX_META_DEPTH"]

MAGIC = b"LWBP"
FORMAT_VERSION = 1
_FLAG_POSE = 0x01
_POSE = struct.Struct("<6f")
MAX_META_DEPTH = 8  # objects/arrays inside the metadata object; codecs use 2 (a sensor table)
_MAX_INT_DIGITS = 19  # |value| < 10**19: any int64 a codec writes
_MAX_TRANSLATION = 1e8  # m: more than the Earth's radius (ECEF poses), less than nonsense
_CODEC_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.:+-]*\Z")


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > _MAX_INT_DIGITS:
        raise PayloadError(f"payload metadata: an integer of {len(text)} digits")
    return int(text)


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise PayloadError(f"payload metadata: non-finite number {text[:20]}")
    return value


def _parse_constant(text: str) -> float:
    raise PayloadError(f"payload metadata: {text} is not a number lwbench accepts")


def _nesting(raw: bytes) -> int:
    """Deepest bracket nesting of JSON text, strings skipped (checked before ``json.loads``,
    whose recursion a deeply nested document exhausts)."""
    if raw.count(b"[") + raw.count(b"{") <= MAX_META_DEPTH + 1:
        return 0  # cannot be deeper than the limit: skip the scan (every real payload)
    depth = deepest = 0
    in_string = escaped = False
    for byte in raw:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:  # quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def parse_meta(raw: bytes) -> dict[str, Any]:
    """The metadata section as a JSON object, bounded (see the module docstring)."""
    if _nesting(raw) > MAX_META_DEPTH + 1:
        raise PayloadError(f"payload metadata nested deeper than {MAX_META_DEPTH} levels")
    try:
        meta = json.loads(
            raw.decode("utf-8"), parse_int=_parse_int, parse_float=_parse_float, parse_constant=_parse_constant
        )
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise PayloadError(f"malformed payload metadata: {type(exc).__name__}: {exc}") from None
    if not isinstance(meta, dict):
        raise PayloadError(f"payload metadata must be a JSON object, not {type(meta).__name__}")
    return meta


def _read_pose(data: bytes, off: int) -> np.ndarray:
    vec = np.array(_POSE.unpack_from(data, off), dtype=np.float64)
    if not np.isfinite(vec).all() or np.abs(vec[:3]).max() > _MAX_TRANSLATION:
        raise PayloadError("payload pose is not finite or lies implausibly far away")
    if np.linalg.norm(vec[3:]) > 4 * math.pi:
        raise PayloadError("payload pose rotation vector is longer than two turns")
    return vec_to_pose(vec)


@dataclass(frozen=True)
class Payload:
    """A parsed payload. ``to_bytes`` and ``from_bytes`` are exact inverses."""

    codec_id: str
    meta: dict[str, Any]
    body: bytes
    pose: np.ndarray | None = field(default=None)

    def to_bytes(self) -> bytes:
        cid = self.codec_id.encode("ascii")
        if not 0 < len(cid) < 256 or not _CODEC_ID.match(self.codec_id):
            raise ValueError(f"codec id must be 1-255 ASCII bytes, got {self.codec_id!r}")
        meta = json.dumps(self.meta, separators=(",", ":"), sort_keys=True).encode("utf-8")
        if len(meta) > 0xFFFF:
            raise ValueError(f"payload metadata too large ({len(meta)} bytes); put data in the body")
        flags = _FLAG_POSE if self.pose is not None else 0
        parts = [MAGIC, struct.pack("<BBB", FORMAT_VERSION, flags, len(cid)), cid]
        parts.append(struct.pack("<H", len(meta)) + meta)
        if self.pose is not None:
            parts.append(_POSE.pack(*pose_to_vec(self.pose)))
        parts.append(struct.pack("<I", len(self.body)) + bytes(self.body))
        blob = b"".join(parts)
        return blob + struct.pack("<I", zlib.crc32(blob))

    @classmethod
    def from_bytes(cls, data: bytes, *, expect_codec: str | None = None) -> Payload:
        data = bytes(data)
        if len(data) < 4 + 3 + 2 + 4 + 4:
            raise PayloadError(f"payload truncated: {len(data)} bytes is shorter than any header")
        if data[:4] != MAGIC:
            raise PayloadError(f"not an lwbench payload (magic {data[:4]!r}, expected {MAGIC!r})")
        (crc,) = struct.unpack_from("<I", data, len(data) - 4)
        if zlib.crc32(data[:-4]) != crc:
            raise PayloadError("payload checksum mismatch: truncated or corrupted in transit")
        version, flags, id_len = struct.unpack_from("<BBB", data, 4)
        if version != FORMAT_VERSION:
            raise PayloadError(
                f"payload format version {version} is not supported (this lwbench reads {FORMAT_VERSION})"
            )
        if flags & ~_FLAG_POSE:
            raise PayloadError(f"payload flags {flags:#04x} hold bits this lwbench does not know")
        try:
            off = 7
            codec_id = data[off : off + id_len].decode("ascii")
            if not _CODEC_ID.match(codec_id):
                raise PayloadError(f"payload codec id {codec_id!r} is not a codec name")
            off += id_len
            (meta_len,) = struct.unpack_from("<H", data, off)
            off += 2
            if off + meta_len > len(data) - 4:
                raise PayloadError("malformed payload: metadata runs past the end")
            meta_raw = data[off : off + meta_len]
            off += meta_len
            pose = None
            if flags & _FLAG_POSE:
                pose = _read_pose(data, off)
                off += _POSE.size
            (body_len,) = struct.unpack_from("<I", data, off)
            off += 4
            body = data[off : off + body_len]
            off += body_len
        except (struct.error, UnicodeDecodeError) as exc:
            raise PayloadError(f"malformed payload header: {exc}") from None
        if off != len(data) - 4 or len(body) != body_len:
            raise PayloadError("malformed payload: section lengths do not add up")
        meta = parse_meta(meta_raw)
        if expect_codec is not None and codec_id != expect_codec:
            raise PayloadError(f"payload is for codec {codec_id!r}, not {expect_codec!r}")
        return cls(codec_id, meta, body, pose)
