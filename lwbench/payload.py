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
"""

from __future__ import annotations

import json
import struct
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.errors import PayloadError
from lwbench.geometry import pose_to_vec, vec_to_pose

__all__ = ["Payload", "PayloadError", "FORMAT_VERSION", "MAGIC"]

MAGIC = b"LWBP"
FORMAT_VERSION = 1
_FLAG_POSE = 0x01
_POSE = struct.Struct("<6f")


@dataclass(frozen=True)
class Payload:
    """A parsed payload. ``to_bytes`` and ``from_bytes`` are exact inverses."""

    codec_id: str
    meta: dict[str, Any]
    body: bytes
    pose: np.ndarray | None = field(default=None)

    def to_bytes(self) -> bytes:
        cid = self.codec_id.encode("ascii")
        if not 0 < len(cid) < 256:
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
        try:
            off = 7
            codec_id = data[off : off + id_len].decode("ascii")
            off += id_len
            (meta_len,) = struct.unpack_from("<H", data, off)
            off += 2
            meta = json.loads(data[off : off + meta_len].decode("utf-8"))
            off += meta_len
            pose = None
            if flags & _FLAG_POSE:
                pose = vec_to_pose(np.array(_POSE.unpack_from(data, off)))
                off += _POSE.size
            (body_len,) = struct.unpack_from("<I", data, off)
            off += 4
            body = data[off : off + body_len]
            off += body_len
        except (struct.error, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise PayloadError(f"malformed payload header: {exc}") from None
        if off != len(data) - 4 or len(body) != body_len or not isinstance(meta, dict):
            raise PayloadError("malformed payload: section lengths do not add up")
        if expect_codec is not None and codec_id != expect_codec:
            raise PayloadError(f"payload is for codec {codec_id!r}, not {expect_codec!r}")
        return cls(codec_id, meta, body, pose)
