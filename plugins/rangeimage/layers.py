"""Every return on the grid: a first layer, an overflow list and exceptions, with their offsets.

Encode (:func:`build_layers`): each return goes to its cell (:mod:`.grid`), with two integer
*offset codes* -- where it sits in azimuth and elevation relative to the cell's anchored ray, in
units of ``q`` times the spacing. The nearest return of each cell is the cell's layer-0 value;
the others (dual returns, coincident beams, firings drifting into one column) are the overflow
list, in cell order, each coded against its cell's layer-0 value. A return the grid cannot
describe -- further than :data:`EXCEPTION_SPACINGS` median beam spacings from its row, such as
the "no return" filler points some drivers write next to the origin -- is an exception, kept as
its float32 x, y, z.

Sections of the body, in this order (sizes follow from the header's counts, so the decoder
knows the exact length before inflating anything):

====================  ==============================================================
row table             per row: phase (uint16, 1/65536 column), offset (int32, 1e-7 rad)
mask                  one bit per cell: has a layer-0 return (``np.packbits``, row-major)
layer-0 ranges        one value per set bit (``width`` bytes), sparse row-delta
                      (absent for the image bodies, which carry the whole image)
layer-0 codes         azimuth codes, then elevation codes (``code_width`` bytes each)
overflow cells        cell index minus the previous overflow cell's (4 bytes)
overflow ranges       value minus the cell's layer-0 value, zig-zag (``width`` bytes)
overflow codes        azimuth, then elevation codes (zig-zag)
exceptions            float32 x, y, z
====================  ==============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from lwbench_plugins.rangeimage.grid import MAX_OFFSET, OFFSET_UNIT, PHASE_LEVELS, Grid, elevation_units
from lwbench_plugins.rangeimage.transform import from_planes, pack_sparse, to_planes, unpack_sparse

from lwbench import PayloadError, SensorModel

__all__ = [
    "EXCEPTION_SPACINGS",
    "Layers",
    "build_layers",
    "code_width",
    "directions",
    "read_sections",
    "section_sizes",
    "write_sections",
]

#: A return further than this many median beam spacings from its row's ray is an exception.
EXCEPTION_SPACINGS = 4.0
# Offset codes stay inside int32 with room for the deltas' sign.
_CODE_LIMIT = 1 << 30


@dataclass
class Layers:
    """The integer content of a payload (before the byte transforms)."""

    grid: Grid
    mask: np.ndarray  # (n_beams, columns) bool: a layer-0 return
    values0: np.ndarray  # int64, one per set mask bit (row-major): quantized range or float32 bits
    az0: np.ndarray  # int64 offset codes of the layer-0 returns
    el0: np.ndarray
    ov_cell: np.ndarray  # int64 flat cell index of each overflow return (non-decreasing)
    ov_values: np.ndarray
    ov_az: np.ndarray
    ov_el: np.ndarray
    exceptions: np.ndarray  # (k, 3) float32
    # Encoder side only (not in the payload): the index, into the points given to
    # build_layers, of each return in decode order (layer 0 row-major, overflow, exceptions).
    source: np.ndarray | None = None

    @property
    def n_returns(self) -> int:
        return len(self.values0) + len(self.ov_values) + len(self.exceptions)


def _median_spacing(sensor: SensorModel) -> float:
    e = sensor.elevations_rad
    gaps = np.diff(e)
    gaps = gaps[gaps > 1e-9]
    return float(np.median(gaps)) if len(gaps) else sensor.azimuth_step_rad


def build_layers(points: np.ndarray, az: np.ndarray, el: np.ndarray, range_bits: np.ndarray, values: np.ndarray,
                 grid: Grid, q: float, verbatim: np.ndarray | None = None) -> Layers:
    """:class:`Layers` of the returns ``points`` (float32, positive range) on ``grid``, with
    offset codes in units of ``q`` spacings.

    ``az``, ``el`` are their directions (rad), ``range_bits`` their float32 ranges' bit patterns
    (which order like the ranges) and ``values`` the coded range values (ordered like them);
    ``verbatim`` marks returns to keep as exceptions whatever their direction (ranges a step
    cannot code).
    Bit-identical points are one return: they share a cell and a range, so one sort by
    (cell, range) finds them next to each other, and it also puts each cell's nearest first.
    """
    sensor = grid.sensor
    nb, n_col = grid.n_beams, grid.columns
    beams = grid.beam_rad
    order = np.argsort(beams, kind="stable")
    mid = (beams[order][1:] + beams[order][:-1]) / 2
    rows = order[np.searchsorted(mid, el)] if nb > 1 else np.zeros(len(el), np.int64)
    u = (az + math.pi) / grid.column_rad - grid.phase[rows]
    col = np.rint(u)
    qa = np.rint((u - col) / q).astype(np.int64)
    col = np.mod(col.astype(np.int64), n_col)
    d_el = el - beams[rows]
    qe_float = np.rint(d_el / (q * elevation_units(sensor)[rows]))
    outside = (np.abs(d_el) > EXCEPTION_SPACINGS * _median_spacing(sensor)) | (np.abs(qe_float) > _CODE_LIMIT)
    if verbatim is not None:
        outside |= verbatim
    qe = np.where(outside, 0, qe_float).astype(np.int64)
    inside = np.flatnonzero(~outside)
    cell = rows * n_col + col
    key = (cell[inside] << 32) | range_bits[inside]
    k = inside[np.argsort(key, kind="stable")]
    key = np.sort(key, kind="stable")
    same = key[1:] == key[:-1]
    if same.any():  # drop exact copies: same cell and range, and the same x, y, z
        xyz = np.ascontiguousarray(points[k]).view(np.uint32).reshape(-1, 3)
        copy = np.r_[False, same & (xyz[1:] == xyz[:-1]).all(axis=1)]
        k, key = k[~copy], key[~copy]
    ck = key >> 32
    first = np.r_[True, ck[1:] != ck[:-1]] if len(k) else np.zeros(0, bool)
    l0, ov = k[first], k[~first]
    mask = np.zeros(nb * n_col, dtype=bool)
    mask[cell[l0]] = True
    verbatim_idx = np.flatnonzero(outside)
    if len(verbatim_idx) > 1:
        _, once = np.unique(points[verbatim_idx].view(np.dtype((np.void, 12))).ravel(), return_index=True)
        verbatim_idx = verbatim_idx[np.sort(once)]
    return Layers(
        grid=grid,
        mask=mask.reshape(nb, n_col),
        values0=values[l0], az0=qa[l0], el0=qe[l0],
        ov_cell=cell[ov], ov_values=values[ov], ov_az=qa[ov], ov_el=qe[ov],
        exceptions=np.asarray(points[verbatim_idx], dtype=np.float32).reshape(-1, 3),
        source=np.concatenate([l0, ov, verbatim_idx]),
    )


def code_width(layers: Layers) -> int:
    """Bytes per offset code: the smallest of 1, 2, 4 that holds every code."""
    codes = [c for c in (layers.az0, layers.el0, layers.ov_az, layers.ov_el) if len(c)]
    if not codes:
        return 1
    lo = min(int(c.min()) for c in codes)
    hi = max(int(c.max()) for c in codes)
    for width in (1, 2, 4):
        if -(1 << (8 * width - 1)) <= lo and hi < 1 << (8 * width - 1):
            return width
    raise ValueError(f"offset codes {lo}..{hi} do not fit in 32 bits")


def section_sizes(sensor: SensorModel, columns: int, cells: int, overflow: int, exceptions: int,
                  width: int, codes: int, with_ranges: bool) -> list[int]:
    """Byte length of each section, from the header's counts alone."""
    return [
        Grid.table_size(sensor),
        (sensor.n_beams * columns + 7) // 8,
        cells * width if with_ranges else 0,
        2 * cells * codes,
        4 * overflow,
        overflow * width,
        2 * overflow * codes,
        12 * exceptions,
    ]


def _overflow_base(layers_mask: np.ndarray, ov_cell: np.ndarray) -> np.ndarray:
    """Position in the layer-0 arrays of each overflow return's cell."""
    flat = layers_mask.ravel()
    rank = np.cumsum(flat) - 1
    return rank[ov_cell]


def write_sections(layers: Layers, width: int, codes: int, predict: str, code_predict: str, shuffle: bool,
                   with_ranges: bool, exact_layer0: bool = True) -> bytes:
    """The raw body (before the entropy coder). ``predict`` is the ranges' predictor,
    ``code_predict`` the layer-0 offset codes'. Overflow ranges are coded against their cell's
    layer-0 value when the decoder gets that value exactly (``exact_layer0``), else as they are;
    overflow codes as they are (measured: their cell's layer-0 codes predict them no better)."""
    mask = layers.mask
    base = _overflow_base(mask, layers.ov_cell)
    cell_step = np.diff(layers.ov_cell, prepend=0)
    bits = 8 * width
    reference = layers.values0[base] if exact_layer0 else 0
    ov_range = (layers.ov_values - reference) & ((1 << bits) - 1)
    parts = [
        layers.grid.table_bytes(),
        np.packbits(mask).tobytes(),
        pack_sparse(layers.values0, mask, width, predict, shuffle) if with_ranges else b"",
        pack_sparse(layers.az0, mask, codes, code_predict, shuffle, signed=True),
        pack_sparse(layers.el0, mask, codes, code_predict, shuffle, signed=True),
        to_planes(cell_step, 4, shuffle),
        to_planes(ov_range, width, shuffle),
        to_planes(_zig(layers.ov_az, codes), codes, shuffle),
        to_planes(_zig(layers.ov_el, codes), codes, shuffle),
        layers.exceptions.astype("<f4").tobytes(),
    ]
    return b"".join(parts)


def _zig(d: np.ndarray, width: int) -> np.ndarray:
    bits = 8 * width
    d = d & ((1 << bits) - 1)
    d = np.where(d >= 1 << (bits - 1), d - (1 << bits), d)
    return (d << 1) ^ (d >> 63)


def _unzig(v: np.ndarray) -> np.ndarray:
    return (v >> 1) ^ -(v & 1)


def _signed(v: np.ndarray, width: int) -> np.ndarray:
    bits = 8 * width
    v = v & ((1 << bits) - 1)
    return np.where(v >= 1 << (bits - 1), v - (1 << bits), v)


def read_sections(raw: bytes, sensor: SensorModel, columns: int, counts: tuple[int, int, int], width: int,
                  codes: int, predict: str, code_predict: str, shuffle: bool, values0: np.ndarray | None,
                  exact_layer0: bool = True) -> Layers:
    """Inverse of :func:`write_sections`. ``values0`` are the layer-0 values when an image body
    carried them (else they are read here). Raises ``PayloadError`` on anything inconsistent."""
    cells, overflow, exceptions = counts
    sizes = section_sizes(sensor, columns, cells, overflow, exceptions, width, codes, values0 is None)
    if len(raw) != sum(sizes):
        raise PayloadError(f"rangeimage payload: body holds {len(raw)} bytes, its counts need {sum(sizes)}")
    offsets = np.cumsum([0, *sizes])
    sec = [raw[offsets[i]:offsets[i + 1]] for i in range(len(sizes))]
    nb = sensor.n_beams
    phase = np.frombuffer(sec[0], "<u2", nb).astype(np.float64) / PHASE_LEVELS
    offset = np.frombuffer(sec[0], "<i4", nb, offset=2 * nb).astype(np.float64) * OFFSET_UNIT
    if np.abs(offset).max(initial=0.0) > MAX_OFFSET + OFFSET_UNIT:
        raise PayloadError("rangeimage payload: a row's elevation offset is beyond the bound")
    mask = np.unpackbits(np.frombuffer(sec[1], np.uint8), count=nb * columns).astype(bool).reshape(nb, columns)
    if int(mask.sum()) != cells:
        raise PayloadError(f"rangeimage payload: the mask holds {int(mask.sum())} returns, the header says {cells}")
    if values0 is None:
        values0 = unpack_sparse(sec[2], mask, width, predict, shuffle)
    az0 = unpack_sparse(sec[3][: cells * codes], mask, codes, code_predict, shuffle, signed=True)
    el0 = unpack_sparse(sec[3][cells * codes:], mask, codes, code_predict, shuffle, signed=True)
    ov_cell = np.cumsum(from_planes(sec[4], overflow, 4, shuffle))
    if overflow and (ov_cell[-1] >= nb * columns or not mask.ravel()[ov_cell].all()):
        raise PayloadError("rangeimage payload: an overflow return lies in a cell without a first return")
    base = _overflow_base(mask, ov_cell)
    bits = 8 * width
    reference = values0[base].astype(np.int64) if exact_layer0 else 0
    ov_values = (reference + from_planes(sec[5], overflow, width, shuffle)) & ((1 << bits) - 1)
    ov_az = _signed(_unzig(from_planes(sec[6][: overflow * codes], overflow, codes, shuffle)), codes)
    ov_el = _signed(_unzig(from_planes(sec[6][overflow * codes:], overflow, codes, shuffle)), codes)
    exc = np.frombuffer(sec[7], "<f4").reshape(exceptions, 3)
    return Layers(Grid(sensor, columns, phase, offset), mask, values0, az0, el0, ov_cell, ov_values, ov_az, ov_el, exc)


def directions(layers: Layers, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction (float64) of every layer-0 and every overflow return, in that order."""
    grid = layers.grid
    rows, cols = np.nonzero(layers.mask)
    ov_rows, ov_cols = np.divmod(layers.ov_cell, grid.columns)
    rows = np.r_[rows, ov_rows]
    cols = np.r_[cols, ov_cols]
    qa = np.r_[layers.az0, layers.ov_az]
    qe = np.r_[layers.el0, layers.ov_el]
    az = -math.pi + (cols + grid.phase[rows] + qa * q) * grid.column_rad
    el = grid.beam_rad[rows] + qe * q * elevation_units(grid.sensor)[rows]
    c = np.cos(el)
    return np.stack([c * np.cos(az), c * np.sin(az), np.sin(el)], axis=1), np.r_[layers.values0, layers.ov_values]
