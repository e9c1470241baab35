"""VSGP payload body: the paper's "3 floats per inducing point + hyper-parameters".

Layout (little endian)::

    M          u32      number of inducing points
    hyper      6 x f32  ls_az, ls_el (rad), alpha, outputscale, noise variance, r_oc (m)
    points     per format, planar (all azimuths, then elevations, then values):
      float32  3*M x f32
      float16  3*M x f16
      q16      3*M x u16  fixed point: azimuth over [-pi, pi], elevation over the sensor's
                          beam span, value over [-r_oc, r_oc] (q(u)'s mean can overshoot
                          below 0 next to a range edge)
      q16z     u32 length L, then L bytes: zstd of the q16 planes, azimuth delta-coded
                          (the layout emits inducing points row by row, so deltas are small)

Body size, exactly: ``28 + 12 M`` (float32), ``28 + 6 M`` (float16, q16), ``32 + L`` (q16z).
The pose travels in the shared header (``make_payload``), the sensor in the JSON metadata.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from lwbench import PayloadError, check_count, zstd_decompress

__all__ = ["BODY_FORMATS", "HEADER", "MAX_INDUCING", "body_size", "pack_body", "unpack_body"]

#: Inducing points a payload may carry: 4x the paper's largest M (600 -> 2,048). M = 20,000 in
#: a 240 KB payload took 133 s and 9.5 GB to decode (an M x M factorization and an
#: (cells x M) kernel).
MAX_INDUCING = 2048
# Hyper-parameters a decoder accepts (finite, positive, and nowhere near float overflow in the
# kernel): lengthscales in radians, RQ shape, prior variance, noise, occupancy radius in m.
_HYPER_BOUNDS = ((1e-5, 1e4), (1e-5, 1e4), (1e-4, 1e6), (1e-10, 1e10), (1e-12, 1e10), (1e-3, 1e4))

BODY_FORMATS = ("float32", "float16", "q16", "q16z")
HEADER = struct.Struct("<I6f")
_BYTES_PER_VALUE = {"float32": 4, "float16": 2, "q16": 2}
_ZSTD_LEVEL = 19
_Q = 65535.0


def body_size(fmt: str, m: int) -> int:
    """Exact body length for the fixed-size formats (``q16z`` depends on the data)."""
    if fmt not in _BYTES_PER_VALUE:
        raise ValueError(f"{fmt} has no closed-form size")
    return HEADER.size + 3 * m * _BYTES_PER_VALUE[fmt]


def _ranges(el_span: tuple[float, float], r_oc: float) -> np.ndarray:
    lo = np.array([-math.pi, el_span[0], -r_oc])
    hi = np.array([math.pi, el_span[1], r_oc])
    return np.stack([lo, hi])


def _quantize(planes: np.ndarray, el_span: tuple[float, float], r_oc: float) -> np.ndarray:
    lo, hi = _ranges(el_span, r_oc)
    q = np.round((planes - lo[:, None]) / (hi - lo)[:, None] * _Q)
    return np.clip(q, 0, _Q).astype("<u2")


def _dequantize(q: np.ndarray, el_span: tuple[float, float], r_oc: float) -> np.ndarray:
    lo, hi = _ranges(el_span, r_oc)
    return lo[:, None] + q.astype(np.float64) / _Q * (hi - lo)[:, None]


def pack_body(fmt: str, z: np.ndarray, u: np.ndarray, hyper: list[float], r_oc: float,
              el_span: tuple[float, float]) -> bytes:
    """Serialize inducing inputs ``z (M, 2)``, values ``u (M,)`` and the hyper-parameters."""
    m = len(u)
    head = HEADER.pack(m, *hyper, r_oc)
    planes = np.stack([z[:, 0], z[:, 1], u]) if m else np.zeros((3, 0))
    if fmt in ("float32", "float16"):
        return head + planes.astype("<f4" if fmt == "float32" else "<f2").tobytes()
    if el_span[1] <= el_span[0]:  # single-beam sensor: nothing to quantize along elevation
        el_span = (el_span[0] - 1e-3, el_span[0] + 1e-3)
    q = _quantize(planes, el_span, r_oc)
    if fmt == "q16":
        return head + q.tobytes()
    import zstandard

    q[0] = np.diff(q[0], prepend=np.uint16(0))  # wraps modulo 2^16, undone by cumsum
    blob = zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(q.tobytes())
    return head + struct.pack("<I", len(blob)) + blob


def unpack_body(fmt: str, body: bytes, el_span: tuple[float, float]
                ) -> tuple[np.ndarray, np.ndarray, list[float], float]:
    """Inverse of :func:`pack_body`; every inconsistency raises :class:`PayloadError`."""
    if fmt not in BODY_FORMATS:
        raise PayloadError(f"vsgp payload: unknown body format {fmt!r}")
    if len(body) < HEADER.size:
        raise PayloadError(f"vsgp payload: body of {len(body)} bytes is shorter than its header")
    m, *vals = HEADER.unpack_from(body)
    hyper, r_oc = vals[:5], vals[5]
    if not all(math.isfinite(v) and lo <= v <= hi for v, (lo, hi) in zip(vals, _HYPER_BOUNDS, strict=True)):
        raise PayloadError("vsgp payload: hyper-parameters must be finite and within their plausible ranges")
    rest = body[HEADER.size:]
    if fmt == "q16z":
        m = check_count(m, "inducing points", codec="vsgp", limit=MAX_INDUCING)
        if len(rest) < 4 or struct.unpack_from("<I", rest)[0] != len(rest) - 4:
            raise PayloadError("vsgp payload: compressed section length does not match the body")
        raw = zstd_decompress(rest[4:], 6 * m, "vsgp payload", exact=True)
        q = np.frombuffer(raw, dtype="<u2").reshape(3, m).copy()
        q[0] = np.cumsum(q[0], dtype=np.uint16)
    else:
        m = check_count(m, "inducing points", codec="vsgp", limit=MAX_INDUCING, body=len(rest),
                        bytes_each=3 * _BYTES_PER_VALUE[fmt], exact=True)
        if fmt != "q16":
            planes = np.frombuffer(rest, dtype="<f4" if fmt == "float32" else "<f2").reshape(3, m)
            planes = planes.astype(np.float64)
            if not np.isfinite(planes).all():
                raise PayloadError("vsgp payload: non-finite inducing point")
            if m and (np.abs(planes[0]).max() > math.pi + 1e-2 or np.abs(planes[1]).max() > math.pi / 2):
                raise PayloadError("vsgp payload: inducing input outside the sphere's angles")
            return planes[:2].T.copy(), planes[2].copy(), hyper, r_oc
        q = np.frombuffer(rest, dtype="<u2").reshape(3, m)
    if el_span[1] <= el_span[0]:
        el_span = (el_span[0] - 1e-3, el_span[0] + 1e-3)
    planes = _dequantize(q, el_span, r_oc)
    return planes[:2].T.copy(), planes[2].copy(), hyper, r_oc
