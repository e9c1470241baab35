"""The one shared point serializer: how selection codecs' kept points become bytes.

Every selection codec (random, keypoints, PocoNet, voxel) goes through this, so their byte
counts differ only by how many points they keep and the precision asked for -- never by who
wrote the serializer.

Formats (the ``encoding`` parameter every selection codec declares):

- ``float32``: ``N x 3`` little-endian float32, lossless.
- ``quantized``: origin (3 x f32) and step (f32), then each coordinate as an unsigned integer
  offset from the origin in units of ``step``, in 16 bits when the extent allows it and 32 bits
  otherwise. The error per coordinate is at most ``step / 2``.
"""

from __future__ import annotations

import struct

import numpy as np

from lwbench.limits import check_count, check_encodable, checked_cloud
from lwbench.payload import PayloadError

__all__ = ["POINT_ENCODINGS", "pack_points", "unpack_points"]

POINT_ENCODINGS = ("float32", "quantized")
_HEAD = struct.Struct("<BI")  # encoding id, point count
_QHEAD = struct.Struct("<4fB")  # origin xyz, step, bytes per value


def pack_points(points: np.ndarray, encoding: str = "float32", step: float = 0.005, codec: str = "points") -> bytes:
    """The body :func:`unpack_points` reads; ``ValueError`` for points it would refuse (beyond
    :data:`lwbench.limits.MAX_COORDINATE`) and for a quantized extent 32 bits cannot hold."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    check_encodable(pts, codec)
    if encoding == "float32":
        return _HEAD.pack(0, len(pts)) + pts.astype("<f4").tobytes()
    if encoding != "quantized":
        raise ValueError(f"unknown point encoding {encoding!r}; choose from {POINT_ENCODINGS}")
    if not step > 0:
        raise ValueError(f"quantization step must be positive, got {step}")
    origin = pts.min(axis=0) if len(pts) else np.zeros(3, np.float32)
    q = np.rint((pts.astype(np.float64) - origin) / step)
    top = q.max() if len(q) else 0
    if top >= 2**32:  # would wrap around in 32 bits: a silently wrong cloud
        raise ValueError(
            f"{codec}: a quantized extent of {top * step:.6g} m at step {step:g} m needs more than 32 bits per "
            "value; use a coarser quant_step or encoding=float32"
        )
    width = 2 if top < 2**16 else 4
    dtype = "<u2" if width == 2 else "<u4"
    return _HEAD.pack(1, len(pts)) + _QHEAD.pack(*origin.tolist(), step, width) + q.astype(dtype).tobytes()


def unpack_points(body: bytes, codec: str = "points") -> np.ndarray:
    """Inverse of :func:`pack_points`: finite float32 ``(N, 3)``, or :class:`PayloadError`.

    The point count is checked against the bytes the body holds before anything is allocated,
    and the decoded coordinates must be finite (a crafted body can hold NaN bit patterns)."""
    try:
        enc, n = _HEAD.unpack_from(body, 0)
        off = _HEAD.size
        if enc == 0:
            n = check_count(n, "point count", codec=codec, body=len(body) - off, bytes_each=12, exact=True)
            pts = np.frombuffer(body, dtype="<f4", offset=off).reshape(n, 3).astype(np.float32)
            return checked_cloud(pts, codec)
        if enc == 1:
            ox, oy, oz, step, width = _QHEAD.unpack_from(body, off)
            off += _QHEAD.size
            if width not in (2, 4):
                raise PayloadError(f"{codec} payload: quantized points of {width} bytes per value")
            n = check_count(n, "point count", codec=codec, body=len(body) - off, bytes_each=3 * width, exact=True)
            if not all(np.isfinite([ox, oy, oz, step])) or not step > 0:
                raise PayloadError(f"{codec} payload: quantization origin or step is not finite and positive")
            q = np.frombuffer(body, dtype="<u2" if width == 2 else "<u4", offset=off)
            pts = q.reshape(n, 3).astype(np.float64) * step + np.array([ox, oy, oz])
            return checked_cloud(pts, codec)
    except struct.error as exc:
        raise PayloadError(f"{codec} payload: truncated point body: {exc}") from None
    raise PayloadError(f"{codec} payload: unknown point encoding id {enc}")
