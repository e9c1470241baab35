"""Per-beam ray refinement: where, inside its cell, each beam's returns actually lie.

A range image stores one range per (beam, azimuth column); decoding puts the point on the
cell's centre ray. Real sensors do not fire at column centres: an Ouster beam fires at a fixed
azimuth offset from the encoder column (``beam_azimuth_angles``) and its measured elevation
differs from the table (the beam origin sits 1.6 cm off the axis). On the real OS1-128 frames
that puts the returns 5 cm off the centre rays on average.

The fix costs 3 bytes per beam: for every beam, the mean position of its returns inside their
columns (azimuth *phase*, 0..1 of a cell) and their mean elevation offset from the table. The
mean is the least-squares choice of one ray per beam. Both are clamped inside the beam's cell,
so a decoded point still projects back to the cell it came from (the range image is
unchanged). On the Ouster frames this halves the off-ray error; on KITTI, whose firings are not
column-aligned, it changes nothing (measured in ``docs/codecs.md``).

Table layout: ``n_beams`` phases as uint8 codes ``q`` (phase ``(q + 0.5) / 255``, so the cell
centre ``q = 127`` is exact), then ``n_beams`` elevation offsets as little-endian int16 in units
of ``1e-5`` rad.

The encoder and the decoder share one set of allowed offset *codes* per beam
(:func:`offset_code_bounds`): the encoder clips its codes into it and the decoder accepts
exactly it, so no table the encoder writes can be refused. The set always holds code 0 (the
table's own ray). That matters for beam tables with (nearly) coincident beams, which the
per-ring medians of :meth:`SensorModel.from_points` give when several rings mostly hold one
filler point (a sensor writing "no return" as a fixed point next to the origin): a
beam's band then is narrower than the two margins, and clipping a float offset into the
inverted interval ``[lo, hi]`` (what version 2 did) wrote a code below ``lo``.
"""

from __future__ import annotations

import math

import numpy as np

from lwbench import PayloadError, RangeImage, SensorModel

__all__ = ["fit_beam_table", "offset_code_bounds", "read_beam_table", "table_size", "unproject_refined"]

_LEVELS = 255
_ELEV_UNIT = 1e-5  # rad
_MARGIN = 3e-5  # rad kept from the band edge so float rounding never crosses into the next beam
_CAP_CODES = 30000  # outer beams: |offset| <= 0.3 rad, well inside int16


def table_size(sensor: SensorModel) -> int:
    return 3 * sensor.n_beams


def offset_code_bounds(sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest int16 elevation-offset code allowed per beam (int64 arrays).

    A beam may move up to half-way to each neighbour (the projection's nearest-beam
    boundaries) less ``_MARGIN``; where that is negative (neighbours closer than two margins)
    it may not move towards that neighbour at all, so the band always contains 0. The outer
    beams are capped inside the int16 range. The bounds are rounded *inwards* to whole codes,
    so every allowed code decodes inside the band.
    """
    half = np.maximum(np.diff(sensor.elevations_rad) / 2 - _MARGIN, 0.0)
    cap = _CAP_CODES * _ELEV_UNIT
    lo = np.maximum(np.r_[-cap, -half], -cap)
    hi = np.minimum(np.r_[half, cap], cap)
    return np.ceil(lo / _ELEV_UNIT).astype(np.int64), np.floor(hi / _ELEV_UNIT).astype(np.int64)


def fit_beam_table(sensor: SensorModel, points: np.ndarray, image: RangeImage) -> bytes:
    """The table for the returns kept in ``image`` (``points`` = the frame's points)."""
    rows, _ = np.nonzero(image.valid)
    p = np.asarray(points, dtype=np.float64)[image.index[image.valid]]
    nb = sensor.n_beams
    counts = np.bincount(rows, minlength=nb)
    safe = np.maximum(counts, 1)
    u = (np.arctan2(p[:, 1], p[:, 0]) + math.pi) / sensor.azimuth_step_rad
    phase = np.bincount(rows, weights=u - np.floor(u), minlength=nb) / safe
    phase_q = np.where(counts > 0, np.clip(np.floor(phase * _LEVELS), 0, _LEVELS - 1), _LEVELS // 2)
    r = np.linalg.norm(p, axis=1)
    alpha = np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0))
    offset = np.bincount(rows, weights=alpha - sensor.elevations_rad[rows], minlength=nb) / safe
    q_lo, q_hi = offset_code_bounds(sensor)
    offset_q = np.clip(np.rint(offset / _ELEV_UNIT), q_lo, q_hi)
    return phase_q.astype(np.uint8).tobytes() + offset_q.astype("<i2").tobytes()


def read_beam_table(raw: bytes, sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """(phase in cells, elevation offset in rad) per beam; ``PayloadError`` if malformed."""
    nb = sensor.n_beams
    if len(raw) != table_size(sensor):
        raise PayloadError(f"rangeimage payload: beam table has {len(raw)} bytes, expected {3 * nb}")
    phase_q = np.frombuffer(raw, dtype=np.uint8, count=nb)
    if (phase_q >= _LEVELS).any():
        raise PayloadError("rangeimage payload: beam phase code out of range")
    offset_q = np.frombuffer(raw, dtype="<i2", offset=nb).astype(np.int64)
    q_lo, q_hi = offset_code_bounds(sensor)
    if (offset_q < q_lo).any() or (offset_q > q_hi).any():
        raise PayloadError("rangeimage payload: beam elevation offset leaves the beam's band")
    return (phase_q + 0.5) / _LEVELS, offset_q * _ELEV_UNIT


def unproject_refined(sensor: SensorModel, ranges: np.ndarray, phase: np.ndarray,
                      offset: np.ndarray) -> np.ndarray:
    """Like :meth:`SensorModel.unproject`, with each beam's ray moved by its phase and offset."""
    rows, cols = np.nonzero(ranges > 0)
    r = ranges[rows, cols].astype(np.float64)
    az = -math.pi + (cols + phase[rows]) * sensor.azimuth_step_rad
    el = sensor.elevations_rad[rows] + offset[rows]
    xyz = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1) * r[:, None]
    return xyz.astype(np.float32)
