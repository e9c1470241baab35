"""Byte transforms applied to the integer range image before zstd (and undone after)."""

from __future__ import annotations

import numpy as np

__all__ = ["PREDICTORS", "pack_image", "unpack_image"]

PREDICTORS = ("none", "row-delta")


def pack_image(values: np.ndarray, width: int, predict: str, shuffle: bool) -> bytes:
    """Unsigned integer image (values < 2**(8*width)) -> transformed bytes (before zstd).

    ``row-delta`` takes differences modulo ``2**(8*width)``, reads them as signed ``width``-byte
    integers and zig-zag maps them (0, -1, 1, -2 -> 0, 1, 2, 3), so small steps of either sign
    become small codes and every code still fits in ``width`` bytes.
    """
    bits = 8 * width
    v = values.astype(np.int64)
    if predict == "row-delta":
        d = np.diff(v, axis=1, prepend=0) & ((1 << bits) - 1)
        d = np.where(d >= 1 << (bits - 1), d - (1 << bits), d)  # signed representative
        v = (d << 1) ^ (d >> 63)
    raw = np.ascontiguousarray(v.astype(f"<u{width}")).view(np.uint8).reshape(-1, width)
    return (raw.T if shuffle else raw).tobytes()


def unpack_image(raw: bytes, shape: tuple[int, int], width: int, predict: str, shuffle: bool) -> np.ndarray:
    """Inverse of :func:`pack_image` (an int64 image)."""
    n = shape[0] * shape[1]
    planes = np.frombuffer(raw, dtype=np.uint8)
    planes = planes.reshape(width, n).T if shuffle else planes.reshape(n, width)
    v = np.ascontiguousarray(planes).view(f"<u{width}").reshape(shape).astype(np.int64)
    if predict == "row-delta":
        d = (v >> 1) ^ -(v & 1)
        v = np.cumsum(d, axis=1) & ((1 << (8 * width)) - 1)
    return v
