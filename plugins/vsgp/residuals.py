"""The residual layer (``residual=TAU``): the GP surface becomes a *predictor*, and every return
it predicts worse than ``TAU`` metres gets a correction -- every return kept is decoded within
``TAU`` of its range, and every return kept has a decoded point.

Why: outdoors a smooth GP surface smears depth edges -- on KITTI 00 the worst 5 % of paired
returns carried 92-94 % of the squared range error at 50 kB (docs/vsgp.md) -- and its variance
cannot see them (it depends on where the inducing points are, not on the data). And a real scan
holds up to several returns in one cell of the grid (deskewed KITTI: 16 % more returns than
occupied cells), while the GP decodes one point per cell, which capped coverage near 0.8.

So the encoder runs its own decoder's prediction (``decoder.predict_grid``, default settings,
the sensor's own grid) and sends, after the GP body:

- ``occupancy``: one bit per cell of the anchored grid (the returns' cells, not the variance
  rule's: the variance rule is what lost half the cells outdoors);
- ``counts``: per occupied cell, its returns minus one (at most :data:`MAX_SLOTS`), one byte --
  the cell's returns become *slots* in azimuth order, decoded at evenly spread azimuths inside
  the cell (a single return at the centre, two at -1/4 and +1/4 of a step);
- ``coded``: one bit per slot: is the GP's range at the cell off by more than ``TAU``;
- ``values``: for each coded slot ``k = round((r - r_gp) / q)`` with ``q = 2 TAU``, zigzag u16, as
  two byte planes. A coded return is then decoded within ``q / 2 = TAU`` too: the layer is a
  dead-zone quantizer of the GP's residual, and ``TAU`` bounds every kept return's error. Or,
  when it compresses smaller (one flag, the encoder tries both), the coded ranges themselves,
  ``k = round(r / q)``: where the surface misses many returns by metres (outdoors) LZMA finds
  the repeats along a beam in the ranges better than in the residuals (KITTI 00 / Ouster at
  ``TAU`` 0.5: 9.1 / 11.4 kB against 10.0 / 14.3 kB), and on the tunnel it is the other way
  round (0.5 vs 1.0 kB at ``TAU`` 0.1) †.

``q = 2 TAU`` is the measured best of ``q`` = TAU/5, TAU/2, TAU, 2 TAU on KITTI 00 frame 0 and
the Ouster frame (docs/vsgp.md, "Outdoors"): a finer step spends more bytes on the few coded
returns than it saves in error. The GP's range is clamped into the sensor's range window before
it is used (a prediction at ``r_oc`` or beyond is "free space", not a range).

Each section is LZMA2 (raw, no container) with its exact inflated size known from the sections
before it, so a crafted payload is refused before anything big is allocated (at most 3 slots a
cell of the sensor's grid). The slot layout and the coded bits do not depend on the variance
rule or on floating-point details of the prediction -- a decoder on another machine reads the
same slots; a range can differ only by the prediction's rounding.
"""

from __future__ import annotations

import lzma
import math
import struct
from dataclasses import dataclass

import numpy as np

from lwbench import PayloadError, SensorModel
from lwbench.geometry import spherical

from .grid import phases_of

__all__ = [
    "MAX_SLOTS",
    "VALUE_MODES",
    "Slots",
    "ResidualSection",
    "scan_slots",
    "slot_shift",
    "residual_step",
    "clamp_prediction",
    "apply_residuals",
    "pack_residuals",
    "unpack_residuals",
]

#: Returns one cell keeps (more are dropped): 3 covers 99.9 % of deskewed KITTI's returns.
MAX_SLOTS = 3
#: ``|k| <= 32,767`` must hold for every return in the sensor's range window: ``q`` is at least
#: this share of the sensor's max range (0.2 mm at 120 m, far below any useful ``TAU``).
_MIN_STEP_SHARE = 2.0 / 65000.0
_HEAD = struct.Struct("<ffB4I")  # TAU, q, value mode, four section lengths
#: How the coded slots' values are sent: residuals to the GP's range, or the ranges themselves.
VALUE_MODES = ("residual", "absolute")
_LZMA = [{"id": lzma.FILTER_LZMA2, "preset": 9, "pb": 0, "nice_len": 128, "dict_size": 1 << 22}]
_LZMA_DEC = [{"id": lzma.FILTER_LZMA2, "dict_size": 1 << 22}]
_SECTIONS = ("occupancy", "counts", "slot bits", "values")


@dataclass
class Slots:
    """A scan's returns as slots of the anchored grid, row-major cell order, azimuth order within."""

    counts: np.ndarray  # (n_rays,) int64 slots of each cell (0..MAX_SLOTS)
    cell: np.ndarray  # (S,) flat cell index of each slot
    rank: np.ndarray  # (S,) position in its cell
    ranges: np.ndarray  # (S,) float64 metres (the return's own range; 0 on the decoder side)


@dataclass
class ResidualSection:
    """What a residual section carries, parsed."""

    slots: Slots
    coded: np.ndarray  # (S,) bool
    k: np.ndarray  # (coded,) int64 quantized residuals
    tau: float
    q: float
    absolute: bool  # k codes the range itself, not the residual to the prediction


def scan_slots(points: np.ndarray, sensor: SensorModel, phase_codes: np.ndarray) -> Slots:
    """The scan's returns in the sensor's range window on the beams' anchored columns (as
    ``grid.project_anchored``), up to :data:`MAX_SLOTS` per cell."""
    r, az, el = spherical(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    ok = (r >= sensor.min_range) & (r <= sensor.max_range)
    r, az, el = r[ok], az[ok], el[ok]
    beams = sensor.elevations_rad
    rows = np.searchsorted((beams[1:] + beams[:-1]) / 2, el)
    pos = np.mod((az + math.pi) / sensor.azimuth_step_rad - (phases_of(phase_codes)[rows] - 0.5), sensor.n_azimuth)
    cols = np.minimum(np.floor(pos).astype(np.int64), sensor.n_azimuth - 1)
    cell = rows * sensor.n_azimuth + cols
    order = np.lexsort((pos, cell))
    cell, r = cell[order], r[order]
    starts = np.flatnonzero(np.concatenate([[True], cell[1:] != cell[:-1]])) if len(cell) else np.zeros(0, np.int64)
    size = np.diff(np.concatenate([starts, [len(cell)]]))
    rank = np.arange(len(cell)) - np.repeat(starts, size)
    keep = rank < MAX_SLOTS
    counts = np.zeros(sensor.n_rays, dtype=np.int64)
    counts[cell[starts]] = np.minimum(size, MAX_SLOTS)
    return Slots(counts, cell[keep], rank[keep], r[keep])


def slot_shift(slots: Slots) -> np.ndarray:
    """Each slot's azimuth offset from its cell's centre, in steps: evenly spread in the cell."""
    n = slots.counts[slots.cell]
    return (slots.rank + 0.5) / n - 0.5


def slots_of_counts(counts: np.ndarray) -> Slots:
    """The slot layout (no ranges yet) the decoder derives from the cell counts."""
    cell = np.repeat(np.arange(len(counts)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(cell)) - np.repeat(starts, counts)
    return Slots(counts, cell, rank, np.zeros(len(cell)))


def residual_step(tau: float, max_range: float) -> float:
    """The quantizer step ``q`` for threshold ``tau`` on a sensor reaching ``max_range``."""
    return max(2.0 * tau, _MIN_STEP_SHARE * max_range)


def clamp_prediction(ranges: np.ndarray, sensor: SensorModel) -> np.ndarray:
    """The GP's ranges as a predictor: inside the sensor's range window (free space and
    non-finite values become the window's far end)."""
    r = np.nan_to_num(np.asarray(ranges, dtype=np.float64), nan=sensor.max_range, posinf=sensor.max_range)
    return np.clip(r, sensor.min_range, sensor.max_range)


def apply_residuals(
    prediction: np.ndarray, coded: np.ndarray, k: np.ndarray, q: float, sensor: SensorModel, absolute: bool = False
) -> np.ndarray:
    """The decoded range of every slot (encoder and decoder both call this: they agree), in the
    sensor's range window -- where every return it encodes lies, so the clip only cuts error."""
    out = np.array(prediction, dtype=np.float64)
    if absolute:
        out[coded] = k.astype(np.float64) * q
    else:
        out[coded] += k.astype(np.float64) * q
    return np.clip(out, sensor.min_range, sensor.max_range)


def _squeeze(raw: bytes) -> bytes:
    return lzma.compress(raw, format=lzma.FORMAT_RAW, filters=_LZMA)


def _inflate(data: bytes, size: int, what: str) -> bytes:
    d = lzma.LZMADecompressor(format=lzma.FORMAT_RAW, filters=_LZMA_DEC)
    try:
        out = d.decompress(data, max_length=size + 1)
    except lzma.LZMAError as exc:
        raise PayloadError(f"vsgp payload: residual {what} is corrupt ({exc})") from None
    if len(out) != size:
        raise PayloadError(f"vsgp payload: residual {what} inflates to {len(out)} bytes, expected {size}")
    return out


def pack_residuals(slots: Slots, prediction: np.ndarray, tau: float, sensor: SensorModel) -> tuple[bytes, np.ndarray]:
    """The residual section for these slots, given the clamped GP range at each slot's cell
    (``prediction``); and the ranges the decoder will produce (for the caller's checks)."""
    q = residual_step(tau, sensor.max_range)
    err = slots.ranges - prediction
    coded = ~(np.abs(err) <= tau)
    k_res = np.rint(err[coded] / q).astype(np.int64)
    k_abs = np.rint(slots.ranges[coded] / q).astype(np.int64)
    occupied = slots.counts > 0
    squeezed = [
        _squeeze(np.packbits(occupied).tobytes()),
        _squeeze((slots.counts[occupied] - 1).astype(np.uint8).tobytes()),
        _squeeze(np.packbits(coded).tobytes()),
    ]
    by_residual, by_range = _squeeze(_planes((k_res << 1) ^ (k_res >> 63))), _squeeze(_planes(k_abs))
    absolute = len(by_range) < len(by_residual)
    squeezed.append(by_range if absolute else by_residual)
    head = _HEAD.pack(tau, q, int(absolute), *(len(s) for s in squeezed))
    k = k_abs if absolute else k_res
    return head + b"".join(squeezed), apply_residuals(prediction, coded, k, q, sensor, absolute)


def _planes(values: np.ndarray) -> bytes:
    """u16 values as two byte planes (low bytes, then high bytes): LZMA sees the slowly varying
    high bytes as long runs."""
    return np.asarray(values).astype("<u2").view(np.uint8).reshape(-1, 2).T.tobytes()


def unpack_residuals(data: bytes, sensor: SensorModel) -> ResidualSection:
    """A residual section for ``sensor``'s grid, every inconsistency a :class:`PayloadError`."""
    if len(data) < _HEAD.size:
        raise PayloadError("vsgp payload: residual section truncated")
    tau, q, mode, *lens = _HEAD.unpack_from(data)
    if not (math.isfinite(tau) and math.isfinite(q) and tau > 0 and q > 0):
        raise PayloadError("vsgp payload: residual threshold or step invalid")
    if mode >= len(VALUE_MODES):
        raise PayloadError(f"vsgp payload: unknown residual value mode {mode}")
    if _HEAD.size + sum(lens) != len(data):
        raise PayloadError(f"vsgp payload: residual sections take {_HEAD.size + sum(lens)} bytes, got {len(data)}")
    offs = np.cumsum([_HEAD.size, *lens])
    part = [data[offs[i] : offs[i + 1]] for i in range(len(_SECTIONS))]
    n_rays = sensor.n_rays
    occupied = np.unpackbits(np.frombuffer(_inflate(part[0], (n_rays + 7) // 8, _SECTIONS[0]), np.uint8))[:n_rays]
    occupied = occupied.astype(bool)
    extra = np.frombuffer(_inflate(part[1], int(occupied.sum()), _SECTIONS[1]), np.uint8)
    if extra.size and int(extra.max()) >= MAX_SLOTS:
        raise PayloadError(f"vsgp payload: a cell holds more than {MAX_SLOTS} returns")
    counts = np.zeros(n_rays, dtype=np.int64)
    counts[occupied] = extra.astype(np.int64) + 1
    slots = slots_of_counts(counts)
    n_slots = len(slots.cell)
    coded = np.unpackbits(np.frombuffer(_inflate(part[2], (n_slots + 7) // 8, _SECTIONS[2]), np.uint8))[:n_slots]
    coded = coded.astype(bool)
    n_coded = int(coded.sum())
    planes = np.frombuffer(_inflate(part[3], 2 * n_coded, _SECTIONS[3]), np.uint8).reshape(2, n_coded)
    k = np.ascontiguousarray(planes.T).view("<u2").ravel().astype(np.int64)
    absolute = VALUE_MODES[mode] == "absolute"
    if not absolute:
        k = (k >> 1) ^ -(k & 1)  # zigzag
    return ResidualSection(slots, coded, k, float(tau), float(q), absolute)
