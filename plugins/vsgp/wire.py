"""VSGP payload body (codec version 2): the paper's "3 numbers per inducing point +
hyper-parameters", per local GP (tile).

Layout (little endian)::

    transform   u8     0: occupancy f = r_oc - r (the paper's), 1: f = 1/r
    n_bands     u8     bands of beams (grid.py); 1, or ceil(beams / 16)
    n_sectors   u16    azimuth sectors per band
    r_oc        f32    occupancy radius (m): returns at or beyond it are free space
    phases      u8 x n_beams              each beam's firing phase (grid.py)
    per tile (n_bands x n_sectors, band-major):
      M_t       u16    inducing points of the tile
      hyper     6 x f32  ls_az, ls_el (rad), alpha, outputscale, noise variance, offset (the
                       tile's prior mean of f, 0 for the paper's zero-mean GP)
      [lo, hi]  2 x f32  q16 / q16z only: the range the tile's values are quantized over
    points, planar over all tiles in tile order:
      azimuth   u16 x M   -pi + code * 2 pi / 65536 (the GP's column-centre coordinates)
      beam      u8  x M   the beam (row) the inducing point lies on: its elevation is the table's
      value     f32 / f16 / u16 x M   posterior mean of f - offset at the point

``q16z`` is ``u32 length`` + zstd (level 19) of the ``q16`` body with the azimuth plane
delta-coded within each tile (points are laid out beam by beam, so deltas are small).

Body size, exactly: ``8 + B + T * (26 + 8q) + M * (3 + v)`` with ``B`` beams, ``T`` tiles, ``M``
points, ``v`` = 4 (float32) or 2 (float16, q16) bytes a value, ``q`` = 1 for q16. Every count is
checked against the body and the sensor before anything is allocated; the decoder's work is
bounded in ``decoder.py``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from lwbench import PayloadError, check_count, zstd_decompress

from .grid import BAND_BEAMS, MAX_TILES, MIN_SECTOR_COLS, Tiling

__all__ = [
    "BODY_FORMATS",
    "TRANSFORMS",
    "MAX_INDUCING",
    "MAX_TILE_INDUCING",
    "Body",
    "TileModel",
    "body_size",
    "pack_body",
    "unpack_body",
    "quantize_azimuth",
    "AZ_CODES",
]

#: Inducing points one payload may carry: a 128-beam scan at ratio 30 needs ~12,000 (q16z); a
#: 1 MB payload holds at most ~200,000 at 5 bytes each. Each tile's are bounded separately
#: (:data:`MAX_TILE_INDUCING`), so the decoder's work stays local (decoder.py).
MAX_INDUCING = 1 << 16
#: Inducing points of one tile: its M x M factorization and each cell's variance cost M^2 (at
#: 1,024 the factorization alone is a third of the decode budget, decoder.py).
MAX_TILE_INDUCING = 1024
BODY_FORMATS = ("float32", "float16", "q16", "q16z")
TRANSFORMS = ("linear", "inverse")
AZ_CODES = 1 << 16
# Hyper-parameters a decoder accepts: finite, positive, nowhere near float overflow in the
# kernel (lengthscales in rad, RQ shape, prior variance, noise variance); r_oc in m.
_HYPER_BOUNDS = ((1e-5, 1e4), (1e-5, 1e4), (1e-4, 1e6), (1e-12, 1e10), (1e-14, 1e10))
_R_OC_BOUNDS = (1e-3, 1e4)
_OFFSET_BOUND = 1e6
_HEAD = struct.Struct("<BBHf")
_TILE = struct.Struct("<H6f")
_RANGE = struct.Struct("<2f")
_VALUE_DTYPE = {"float32": "<f4", "float16": "<f2", "q16": "<u2"}
_ZSTD_LEVEL = 19
_Q = 65535.0


@dataclass
class TileModel:
    """One tile's part of a payload: inducing azimuth codes, beams, values, hyper-parameters."""

    az_code: np.ndarray  # (M,) uint16
    beam: np.ndarray  # (M,) int64 row index
    value: np.ndarray  # (M,) float64, f - offset
    hyper: tuple[float, float, float, float, float]
    offset: float


@dataclass
class Body:
    transform: str
    r_oc: float
    tiling: Tiling
    phase_codes: np.ndarray  # (n_beams,) uint8
    tiles: list[TileModel]

    @property
    def num_inducing(self) -> int:
        return sum(len(t.value) for t in self.tiles)


def quantize_azimuth(az: np.ndarray) -> np.ndarray:
    """Azimuth (rad) -> u16 code; ``dequantize_azimuth`` gives the value the GP uses."""
    return (np.round((np.asarray(az) + math.pi) / (2 * math.pi) * AZ_CODES).astype(np.int64) % AZ_CODES).astype(
        np.uint16
    )


def dequantize_azimuth(code: np.ndarray) -> np.ndarray:
    return -math.pi + np.asarray(code, dtype=np.float64) * (2 * math.pi / AZ_CODES)


def body_size(fmt: str, n_beams: int, n_tiles: int, m: int) -> int:
    """Exact body length for the fixed-size formats (``q16z`` depends on the data)."""
    if fmt not in _VALUE_DTYPE:
        raise ValueError(f"{fmt} has no closed-form size")
    per_tile = _TILE.size + (_RANGE.size if fmt == "q16" else 0)
    return _HEAD.size + n_beams + n_tiles * per_tile + m * (3 + np.dtype(_VALUE_DTYPE[fmt]).itemsize)


def _value_range(v: np.ndarray) -> tuple[float, float]:
    if not len(v):
        return 0.0, 0.0
    lo, hi = float(np.float32(v.min())), float(np.float32(v.max()))
    return lo, hi


def pack_body(fmt: str, body: Body) -> bytes:
    qfmt = "q16" if fmt == "q16z" else fmt
    head = [
        _HEAD.pack(TRANSFORMS.index(body.transform), body.tiling.n_bands, body.tiling.n_sectors, body.r_oc),
        np.asarray(body.phase_codes, dtype=np.uint8).tobytes(),
    ]
    values = []
    for t in body.tiles:
        head.append(_TILE.pack(len(t.value), *t.hyper, t.offset))
        if qfmt == "q16":
            lo, hi = _value_range(t.value)
            head.append(_RANGE.pack(lo, hi))
            span = hi - lo if hi > lo else 1.0
            values.append(np.clip(np.round((t.value - lo) / span * _Q), 0, _Q).astype("<u2"))
        else:
            values.append(t.value.astype(_VALUE_DTYPE[qfmt]))
    az = [t.az_code.astype("<u2") for t in body.tiles]
    if fmt == "q16z":  # delta within each tile (wraps modulo 2^16, undone by cumsum)
        az = [np.diff(a, prepend=np.uint16(0)).astype("<u2") if len(a) else a for a in az]
    planes = [
        np.concatenate(az).astype("<u2") if az else np.zeros(0, "<u2"),
        np.concatenate([t.beam for t in body.tiles]).astype(np.uint8) if body.tiles else np.zeros(0, np.uint8),
        np.concatenate(values) if values else np.zeros(0, _VALUE_DTYPE[qfmt]),
    ]
    raw = b"".join(head) + b"".join(p.tobytes() for p in planes)
    if fmt != "q16z":
        return raw
    import zstandard

    blob = zstandard.ZstdCompressor(level=_ZSTD_LEVEL).compress(raw)
    return struct.pack("<I", len(raw)) + blob


def _max_raw_size(n_beams: int, n_tiles: int) -> int:
    return _HEAD.size + n_beams + n_tiles * (_TILE.size + _RANGE.size) + MAX_INDUCING * 5


def _check_tiling(n_bands: int, n_sectors: int, n_beams: int, n_cols: int) -> Tiling:
    bands_ok = n_bands in (1, max(1, math.ceil(n_beams / BAND_BEAMS)))
    sectors_ok = 1 <= n_sectors <= max(1, n_cols // MIN_SECTOR_COLS) and n_bands * n_sectors <= MAX_TILES
    if not (bands_ok and sectors_ok):
        raise PayloadError(
            f"vsgp payload: a tiling of {n_bands} bands x {n_sectors} sectors does not fit the "
            f"sensor ({n_beams} beams, {n_cols} columns)"
        )
    return Tiling(n_beams, n_cols, n_bands, n_sectors)


def unpack_body(fmt: str, data: bytes, n_beams: int, n_cols: int) -> Body:
    """Inverse of :func:`pack_body` for a sensor of ``n_beams x n_cols``; every inconsistency
    raises :class:`PayloadError`."""
    if fmt not in BODY_FORMATS:
        raise PayloadError(f"vsgp payload: unknown body format {fmt!r}")
    if fmt == "q16z":
        if len(data) < 4:
            raise PayloadError("vsgp payload: compressed body shorter than its length field")
        (raw_len,) = struct.unpack_from("<I", data)
        limit = _max_raw_size(n_beams, MAX_TILES)
        if raw_len > limit:
            raise PayloadError(f"vsgp payload: compressed body declares {raw_len} bytes, more than {limit}")
        data = zstd_decompress(data[4:], raw_len, "vsgp payload", exact=True)
    qfmt = "q16" if fmt == "q16z" else fmt
    if len(data) < _HEAD.size + n_beams:
        raise PayloadError(f"vsgp payload: body of {len(data)} bytes is shorter than its header")
    code, n_bands, n_sectors, r_oc = _HEAD.unpack_from(data)
    if code >= len(TRANSFORMS):
        raise PayloadError(f"vsgp payload: unknown occupancy transform {code}")
    if not (math.isfinite(r_oc) and _R_OC_BOUNDS[0] <= r_oc <= _R_OC_BOUNDS[1]):
        raise PayloadError("vsgp payload: occupancy radius outside its plausible range")
    tiling = _check_tiling(n_bands, n_sectors, n_beams, n_cols)
    pos = _HEAD.size
    phases = np.frombuffer(data, np.uint8, n_beams, pos).copy()
    pos += n_beams
    per_tile = _TILE.size + (_RANGE.size if qfmt == "q16" else 0)
    check_count(tiling.n_tiles, "tiles", codec="vsgp", limit=(len(data) - pos) // per_tile)
    heads = []
    for _ in range(tiling.n_tiles):
        m_t, *vals = _TILE.unpack_from(data, pos)
        pos += _TILE.size
        hyper, offset = tuple(vals[:5]), vals[5]
        if not all(math.isfinite(v) and lo <= v <= hi for v, (lo, hi) in zip(hyper, _HYPER_BOUNDS, strict=True)):
            raise PayloadError("vsgp payload: hyper-parameters must be finite and within their plausible ranges")
        if not (math.isfinite(offset) and abs(offset) <= _OFFSET_BOUND):
            raise PayloadError("vsgp payload: a tile's offset is not a plausible occupancy")
        m_t = check_count(m_t, "a tile's inducing points", codec="vsgp", limit=MAX_TILE_INDUCING)
        lo = hi = 0.0
        if qfmt == "q16":
            lo, hi = _RANGE.unpack_from(data, pos)
            pos += _RANGE.size
            if not (math.isfinite(lo) and math.isfinite(hi) and -_OFFSET_BOUND <= lo <= hi <= _OFFSET_BOUND):
                raise PayloadError("vsgp payload: a tile's value range is not plausible")
        heads.append((m_t, hyper, offset, lo, hi))
    m = check_count(sum(h[0] for h in heads), "inducing points", codec="vsgp", limit=MAX_INDUCING)
    vbytes = np.dtype(_VALUE_DTYPE[qfmt]).itemsize
    check_count(m, "inducing points", codec="vsgp", body=len(data) - pos, bytes_each=3 + vbytes, exact=True)
    az = np.frombuffer(data, "<u2", m, pos).copy()
    beam = np.frombuffer(data, np.uint8, m, pos + 2 * m).astype(np.int64)
    val = np.frombuffer(data, _VALUE_DTYPE[qfmt], m, pos + 3 * m).astype(np.float64)
    if m and beam.max() >= n_beams:
        raise PayloadError(f"vsgp payload: an inducing point lies on beam {int(beam.max())} of {n_beams}")
    if not np.isfinite(val).all():
        raise PayloadError("vsgp payload: non-finite inducing value")
    tiles, start = [], 0
    for m_t, hyper, offset, lo, hi in heads:
        sl = slice(start, start + m_t)
        a, v = az[sl], val[sl]
        if fmt == "q16z" and m_t:
            a = np.cumsum(a, dtype=np.uint16)
        if qfmt == "q16":
            v = lo + v / _Q * (hi - lo)
        tiles.append(TileModel(a, beam[sl], v, hyper, offset))
        start += m_t
    return Body(TRANSFORMS[code], r_oc, tiling, phases, tiles)
