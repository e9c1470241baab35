"""``cloudini``: Cloudini, the point-cloud compression ROS users stream (through ``pureini``).

Cloudini (Davide Faconti, github.com/facontidavide/cloudini) compresses a ``PointCloud2``'s
bytes in two stages: every FLOAT32 field is quantized to a ``resolution`` and coded as the
zig-zag varint of its difference to the previous point's value (other fields losslessly), then
each chunk of 32,768 points goes through zstd (or LZ4). Its ROS nodes and ``point_cloud_transport``
plugin give every FLOAT32 field one resolution, 1 mm by default, LOSSY + ZSTD; this codec sends
the same message: fields ``x, y, z`` (+ ``intensity`` when the frame has one and
``intensity=true``), FLOAT32, all at ``resolution``, one row of ``len(scan)`` points, in the
scan's order. Every coordinate is within ``resolution/2``: range error at most half the
resolution's cube diagonal, every return kept.

The format is read and written by ``pureini``, a Rust implementation of Cloudini (V2-V5 payloads;
it writes V5). pureini is GPL-3.0, so it is an optional dependency (``pip install
'lwbench[cloudini]'``): lwbench itself stays MIT, and without pureini this codec fails with the
install command instead of importing it.

Bounded decoding: pureini allocates ``width x height x point_step`` bytes from the Cloudini
header and each chunk's zstd frame from its declared size. So the decoder rebuilds the header
this codec writes for the lwbench header's point count and requires the body to start with it
byte for byte, then walks the chunks (a u32 length and one zstd frame each): exactly as many as
the count needs, each declaring its inflated size, at most :data:`MAX_STAGE1_BYTES` per field
and point (a varint of a 32-bit difference), nothing left over. The count must be paid for by
the bytes (at least :data:`MIN_BITS_PER_POINT` bits of body per point; real scans take 15-25 at
1 mm) and stay below :data:`lwbench.MAX_POINTS`.
"""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np

from lwbench import (
    Frame,
    MissingDependencyError,
    Param,
    PayloadError,
    RepresentationCodec,
    check_count,
    checked_cloud,
    hookimpl,
)

__all__ = ["CloudiniCodec", "MIN_BITS_PER_POINT", "MAX_STAGE1_BYTES"]

#: Bits of body each declared point must be paid with (bounds a decode by its input's size).
MIN_BITS_PER_POINT = 4
#: Cloudini's first stage writes at most this many bytes per field and point: the zig-zag
#: varint of a difference of two int32 quantized values (33 bits, 5 groups of 7).
MAX_STAGE1_BYTES = 5
_POINTS_PER_CHUNK = 32_768  # pureini's POINTS_PER_CHUNK (Cloudini's chunking)
_INT32 = 2**31 - 1
_INSTALL = "pip install 'lwbench[cloudini]' (or: pip install pureini)"


def _pureini():
    try:
        import pureini
    except ImportError:
        raise MissingDependencyError(f"the cloudini codec needs pureini (GPL-3.0, not installed): {_INSTALL}") from None
    return pureini


def _encoding_info(n: int, resolution: float, fields: tuple[str, ...]):
    """What Cloudini's ROS converter writes for a cloud of ``fields``: one row, FLOAT32 fields at
    one resolution, LOSSY + ZSTD (pureini's defaults, the current V5 format)."""
    pureini = _pureini()
    return pureini.EncodingInfo(
        fields=[pureini.PointField(f, 4 * i, pureini.FieldType.FLOAT32, resolution) for i, f in enumerate(fields)],
        width=n,
        height=1,
        point_step=4 * len(fields),
        encoding_opt=pureini.EncodingOptions.LOSSY,
        compression_opt=pureini.CompressionOption.ZSTD,
    )


def _check_chunks(body: bytes, start: int, n: int, n_fields: int, codec: str) -> None:
    """The chunks after the header: as many as ``n`` points need, each a length and one zstd
    frame declaring a bounded inflated size, covering the body exactly."""
    import zstandard

    expected = math.ceil(n / _POINTS_PER_CHUNK)
    off, k = start, 0
    while off < len(body):
        if k == expected or off + 4 > len(body):
            raise PayloadError(f"{codec} payload: Cloudini body holds more than the {expected} chunks {n} points need")
        (length,) = struct.unpack_from("<I", body, off)
        frame = body[off + 4 : off + 4 + length]
        if len(frame) != length:
            raise PayloadError(f"{codec} payload: Cloudini chunk {k} runs past the end of the body")
        points = min(_POINTS_PER_CHUNK, n - k * _POINTS_PER_CHUNK)
        try:
            declared = zstandard.frame_content_size(frame)
        except zstandard.ZstdError as exc:
            raise PayloadError(f"{codec} payload: Cloudini chunk {k} is not a zstd frame ({exc})") from None
        if not 0 <= declared <= points * n_fields * MAX_STAGE1_BYTES:
            raise PayloadError(f"{codec} payload: Cloudini chunk {k} declares {declared} bytes for {points} points")
        off += 4 + length
        k += 1
    if k != expected:
        raise PayloadError(f"{codec} payload: Cloudini body holds {k} chunks, {n} points need {expected}")


class CloudiniCodec(RepresentationCodec):
    """Cloudini (pureini): FLOAT32 fields quantized to ``resolution``, delta varints, zstd."""

    name = "cloudini"
    version = "1"
    description = "Cloudini (ROS point-cloud compression, through pureini): xyz at a resolution, varint deltas, zstd"
    params = (
        Param(
            "resolution",
            "float",
            0.001,
            "quantization of every FLOAT32 field, m (Cloudini's default 1 mm)",
            low=1e-6,
            high=10.0,
        ),
        Param("intensity", "bool", True, "send the frame's intensity as a fourth FLOAT32 field when it has one"),
    )

    def encode(self, frame: Frame) -> bytes:
        pureini = _pureini()
        resolution = float(self.config["resolution"])
        columns = [frame.points]
        fields: tuple[str, ...] = ("x", "y", "z")
        if self.config["intensity"] and frame.intensity is not None:
            intensity = np.nan_to_num(np.asarray(frame.intensity, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
            columns.append(intensity[:, None])
            fields = (*fields, "intensity")
        cloud = np.ascontiguousarray(np.concatenate(columns, axis=1), dtype=np.float32)
        if len(cloud) and float(np.abs(cloud).max()) / resolution >= _INT32:
            # Cloudini clamps the quantized value to int32: the value would come back wrong.
            raise ValueError(
                f"cloudini: a value of {float(np.abs(cloud).max()):.1f} does not fit int32 at resolution {resolution}"
            )
        body = pureini.PointcloudEncoder(_encoding_info(len(cloud), resolution, fields)).encode(cloud.tobytes())
        meta: dict[str, Any] = {"n": len(cloud), "resolution": resolution, "fields": list(fields)}
        try:
            self._check(body, len(cloud), resolution, fields)
        except PayloadError as exc:  # never write what the decoder refuses
            raise ValueError(f"cloudini: cannot send this scan at resolution {resolution}: {exc}") from None
        return self.make_payload(frame, meta, bytes(body))

    def _check(self, body: bytes, n: int, resolution: float, fields: tuple[str, ...]) -> None:
        check_count(n, "point count", codec=self.name, body=len(body), bytes_each=MIN_BITS_PER_POINT / 8)
        header = _pureini().PointcloudEncoder(_encoding_info(n, resolution, fields)).header
        if not body.startswith(header):
            raise PayloadError(f"{self.name} payload: the Cloudini header is not the one for {n} points of {fields}")
        _check_chunks(body, len(header), n, len(fields), self.name)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name)
        resolution = self.meta_field(payload, "resolution", float)
        fields = tuple(self.meta_field(payload, "fields", list))
        if fields not in (("x", "y", "z"), ("x", "y", "z", "intensity")):
            raise PayloadError(f"{self.name} payload: fields {list(fields)[:5]} are not what this codec sends")
        if not 1e-6 <= resolution <= 10.0:
            raise PayloadError(f"{self.name} payload: resolution {resolution} is outside [1e-6, 10] m")
        self._check(payload.body, n, resolution, fields)
        try:
            raw, info = _pureini().PointcloudDecoder().decode(payload.body)
        except MemoryError:
            raise PayloadError(f"{self.name} payload: the Cloudini body asks for more memory than allowed") from None
        except BaseException as exc:  # pureini raises ValueError, Rust panics are BaseException
            if isinstance(exc, KeyboardInterrupt | SystemExit | GeneratorExit):
                raise
            raise PayloadError(f"{self.name} payload: body is not a valid Cloudini message ({exc})") from None
        if len(raw) != 4 * len(fields) * n:
            raise PayloadError(f"{self.name} payload: Cloudini decoded {len(raw)} bytes for {n} points")
        cloud = np.frombuffer(raw, dtype="<f4").reshape(n, len(fields))
        return checked_cloud(cloud[:, :3], self.name)


@hookimpl
def lwbench_codecs() -> list[type[CloudiniCodec]]:
    return [CloudiniCodec]
