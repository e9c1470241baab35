"""``cloudini``: Cloudini, the point-cloud compression ROS users stream, in lwbench's own code.

Cloudini (Davide Faconti, github.com/facontidavide/cloudini, Apache-2.0) compresses a
``PointCloud2``'s bytes in two stages: every FLOAT32 field is quantized to a ``resolution`` and
coded as the zig-zag varint of its difference to the previous point's value (other fields
losslessly), then each chunk of 32,768 points goes through zstd (or LZ4). Its ROS nodes and
``point_cloud_transport`` plugin give every FLOAT32 field one resolution, 1 mm by default,
LOSSY + ZSTD; this codec sends the same message: fields ``x, y, z`` (+ ``intensity`` when the
frame has one and ``intensity=true``), FLOAT32, all at ``resolution``, one row of ``len(scan)``
points, in the scan's order. Every coordinate is within ``resolution/2``: range error at most
half the resolution's cube diagonal, every return kept.

The message is written and read by :mod:`lwbench_plugins.cloudini.v5` (numpy + zstandard, the
format's description there): the Rust implementation on PyPI, ``pureini``, is GPL-3.0, and
lwbench (MIT) uses GPL code only as a test oracle -- the tests check that pureini reads what
this codec writes, that this codec reads what pureini writes, and that the bytes are the same.

Bounded decoding: the decoder rebuilds the header this codec writes for the lwbench header's
point count and requires the body to start with it byte for byte, then walks the chunks (a u32
length and one zstd frame each): exactly as many as the count needs, each declaring its
inflated size, between one and :data:`MAX_STAGE1_BYTES` bytes per field and point (a varint of
an int32 difference), nothing left over -- all before anything is inflated; each frame then
inflates to exactly its declared size (``lwbench.zstd_decompress``) and must hold exactly its
points' varints. The count must be paid for by the bytes (at least :data:`MIN_BITS_PER_POINT`
bits of body per point; real scans take 15-25 at 1 mm) and stay below :data:`lwbench.MAX_POINTS`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from lwbench_plugins.cloudini.v5 import MAX_VARINT_BYTES, read_body, write_body

from lwbench import Frame, Param, PayloadError, RepresentationCodec, check_count, checked_cloud, hookimpl

__all__ = ["CloudiniCodec", "MIN_BITS_PER_POINT", "MAX_STAGE1_BYTES", "read_cloudini"]

#: Bits of body each declared point must be paid with (bounds a decode by its input's size).
MIN_BITS_PER_POINT = 4
#: Cloudini's first stage writes at most this many bytes per field and point: the zig-zag
#: varint of a difference of two int32 quantized values (33 bits, 5 groups of 7).
MAX_STAGE1_BYTES = MAX_VARINT_BYTES
_FIELDS = (("x", "y", "z"), ("x", "y", "z", "intensity"))
_RESOLUTION = (1e-6, 10.0)
_META = (("n", int), ("resolution", float), ("fields", list))  # what the lwbench header carries


class CloudiniCodec(RepresentationCodec):
    """Cloudini V5: FLOAT32 fields quantized to ``resolution``, delta varints, zstd."""

    name = "cloudini"
    version = "1"
    description = "Cloudini (ROS point-cloud compression, V5 messages): xyz at a resolution, varint deltas, zstd"
    params = (
        Param(
            "resolution",
            "float",
            0.001,
            "quantization of every FLOAT32 field, m (Cloudini's default 1 mm)",
            low=_RESOLUTION[0],
            high=_RESOLUTION[1],
        ),
        Param("intensity", "bool", True, "send the frame's intensity as a fourth FLOAT32 field when it has one"),
    )

    def encode(self, frame: Frame) -> bytes:
        resolution = float(self.config["resolution"])
        columns = [np.asarray(frame.points, dtype=np.float32)]
        fields = _FIELDS[0]
        if self.config["intensity"] and frame.intensity is not None:
            intensity = np.nan_to_num(np.asarray(frame.intensity, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
            columns.append(intensity[:, None])
            fields = _FIELDS[1]
        cloud = np.concatenate(columns, axis=1)
        body = write_body(cloud, resolution, fields)  # ValueError for a value beyond int32 quanta
        if len(body) * 8 < MIN_BITS_PER_POINT * len(cloud):  # never write what the decoder refuses
            raise ValueError(
                f"cloudini: cannot send this scan at resolution {resolution}: {len(body)} bytes for "
                f"{len(cloud)} points, below the decoder's {MIN_BITS_PER_POINT} bits per point"
            )
        meta: dict[str, Any] = {"n": len(cloud), "resolution": resolution, "fields": list(fields)}
        return self.make_payload(frame, meta, body)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        meta = {key: self.meta_field(payload, key, kind) for key, kind in _META}
        cloud = read_cloudini(payload.body, meta["n"], meta["resolution"], tuple(meta["fields"]), self.name)
        return checked_cloud(cloud[:, :3], self.name)


def read_cloudini(
    body: bytes, n: int, resolution: float, fields: tuple[str, ...], codec: str = "cloudini"
) -> np.ndarray:
    """Every field ``(n, len(fields))`` float32 (NaN where the message says so) of a Cloudini
    body as :class:`CloudiniCodec` writes it for these settings, or ``PayloadError``."""
    if fields not in _FIELDS:
        raise PayloadError(f"{codec} payload: fields {list(fields)[:5]} are not what this codec sends")
    if not _RESOLUTION[0] <= resolution <= _RESOLUTION[1]:
        raise PayloadError(f"{codec} payload: resolution {resolution} is outside [1e-6, 10] m")
    n = check_count(n, "point count", codec=codec, body=len(body), bytes_each=MIN_BITS_PER_POINT / 8)
    return read_body(body, n, resolution, fields, codec)


@hookimpl
def lwbench_codecs() -> list[type[CloudiniCodec]]:
    return [CloudiniCodec]
