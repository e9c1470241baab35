"""The codec's grid, derived from the scan: how many columns, where each row's firings sit.

A range image is only as good as its grid. A fixed grid -- columns every ``360 / n`` degrees from
-180, rows at the beam table -- measures where the cell edges fall as much as the scan: real
firings are not at cell centres (an Ouster beam fires at its own azimuth offset, a Velodyne's
clock drifts against any fixed step, a deskewed scan has no lattice at all), so two firings land
in one cell and one of them was lost, or a firing is decoded half a cell from where it was.

So the grid follows the data:

- **columns**: when the returns of each row lie on a lattice of firings (the same step for every
  row, each row at its own phase), its period -- found as the integer column count whose
  per-row phase coherence :func:`coherence` is largest near the step between neighbouring
  returns -- is the column count. When no lattice holds (coherence below
  :data:`LATTICE_COHERENCE`: deskewed or resampled scans), the sensor model's own count is kept;
  then no column count is better than another and every return carries its offset anyway.
- **rows**: the beam table of the sensor model; each return goes to the beam nearest its
  elevation after each beam's own offset (the median of its returns' offsets from the table);
- **anchors**: each row's azimuth *phase* (the circular mean of where its returns sit inside
  their columns) and elevation offset, so that a firing on the lattice is decoded exactly there;
- **offsets**: what is left, per return, in units of a fraction ``q`` of the grid's spacing
  (:func:`elevation_units`: the local beam spacing, as the range metrics measure it), rounded.
  A decoded direction is then within ``q / 2`` spacings of the original along each axis.

Nothing here depends on where the scan starts: rotating it by any angle rotates the phases.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lwbench import SensorModel

__all__ = [
    "Grid",
    "LATTICE_COHERENCE",
    "PHASE_LEVELS",
    "OFFSET_UNIT",
    "MAX_OFFSET",
    "coherence",
    "derive_grid",
    "elevation_units",
    "fixed_grid",
    "grid_model",
    "lattice_columns",
]

#: A row's returns form a lattice when the mean of ``exp(2 pi i u)`` over their column positions
#: ``u`` has at least this length (1: every return at one phase; 0: uniformly spread).
#: ``lwbench.testing.room_scan``'s clock, drifting by 0.1-0.4 of a step over the sweep, gives
#: 0.86-0.97 (seeds 0-3); a real Ouster frame 0.99; a deskewed KITTI frame 0.05.
LATTICE_COHERENCE = 0.5
#: Row phases are stored as uint16 codes: ``phase = code / PHASE_LEVELS`` of a column.
PHASE_LEVELS = 1 << 16
#: Row elevation offsets are stored as int32 codes in units of this many radians ...
OFFSET_UNIT = 1e-7
#: ... of at most this size (28.6 degrees: further than any table is wrong).
MAX_OFFSET = 0.5
# Points used to test a candidate column count (deterministic stride through the scan).
_SAMPLE = 20000
# Candidate column counts tried around the estimate from neighbouring azimuth steps.
_CANDIDATES = 2


@dataclass(frozen=True)
class Grid:
    """Rows (the sensor's beam table), ``columns`` columns, per-row phase and elevation offset."""

    sensor: SensorModel
    columns: int
    phase: np.ndarray  # (n_beams,) float64, in columns, a multiple of 1 / PHASE_LEVELS
    offset: np.ndarray  # (n_beams,) float64, rad, a multiple of OFFSET_UNIT

    @property
    def n_beams(self) -> int:
        return self.sensor.n_beams

    @property
    def n_cells(self) -> int:
        return self.n_beams * self.columns

    @property
    def column_rad(self) -> float:
        return 2 * math.pi / self.columns

    @property
    def beam_rad(self) -> np.ndarray:
        """Each row's anchored elevation: the table plus the row's offset."""
        return self.sensor.elevations_rad + self.offset

    def table_bytes(self) -> bytes:
        codes = np.rint(self.phase * PHASE_LEVELS).astype("<u2")
        return codes.tobytes() + np.rint(self.offset / OFFSET_UNIT).astype("<i4").tobytes()

    @staticmethod
    def table_size(sensor: SensorModel) -> int:
        return 6 * sensor.n_beams

    def model(self) -> SensorModel:
        """The grid as a sensor model (the table, ``columns`` columns): ``ValueError`` when
        that is more cells than a sensor has (:class:`lwbench.SensorModel`'s bounds)."""
        return grid_model(self.sensor, self.columns)


def grid_model(sensor: SensorModel, columns: int) -> SensorModel:
    """``sensor`` with ``columns`` columns (``ValueError`` beyond a real sensor's bounds)."""
    if columns == sensor.n_azimuth:
        return sensor
    s = sensor
    return SensorModel(f"{s.name}/{columns}", s.elevations_deg, 360.0 / columns, s.min_range, s.max_range, s.rate_hz)


def elevation_units(sensor: SensorModel) -> np.ndarray:
    """Per row, the elevation spacing the range metrics use around it: the gap to the nearest
    *distinct* neighbouring beam (coincident beams, which tables derived from scans can hold,
    count as one), the azimuth step for a single-beam sensor. Floored at 1e-6 rad."""
    e = sensor.elevations_rad
    distinct = e[np.r_[True, np.diff(e) > 1e-9]]
    if len(distinct) == 1:
        return np.full(len(e), max(sensor.azimuth_step_rad, 1e-6))
    gaps = np.diff(distinct)
    below = np.r_[gaps[0], gaps]  # gap to the next distinct beam below each distinct beam
    above = np.r_[gaps, gaps[-1]]
    local = np.minimum(below, above)
    where = np.searchsorted(distinct, e - 1e-9)  # each beam's distinct group
    return np.maximum(local[np.clip(where, 0, len(distinct) - 1)], 1e-6)


def coherence(az: np.ndarray, rows: np.ndarray, n_beams: int, columns: int) -> float:
    """Mean over rows (weighted by their returns) of the phase coherence at ``columns`` columns."""
    z = np.exp(1j * columns * az)
    s = np.abs(np.bincount(rows, z.real, n_beams) + 1j * np.bincount(rows, z.imag, n_beams))
    return float(s.sum() / max(len(az), 1))


def _typical_step(az: np.ndarray, rows: np.ndarray, guess: float) -> float:
    """The step between neighbouring returns of a row: the mean of the steps near their median
    (gaps of dropped returns and returns of one firing are ignored)."""
    order = np.lexsort((az, rows))
    d = np.diff(az[order])
    d = d[(np.diff(rows[order]) == 0) & (d > 1e-9)]
    d = d[(d > 0.5 * guess) & (d < 1.5 * guess)]
    if not len(d):
        return guess
    med = float(np.median(d))
    near = d[(d > 0.8 * med) & (d < 1.2 * med)]
    return float(near.mean()) if len(near) else med


def lattice_columns(az: np.ndarray, rows: np.ndarray, sensor: SensorModel) -> int:
    """The column count of the scan's firing lattice, or the sensor's when there is none."""
    fallback = sensor.n_azimuth
    if len(az) < 16:
        return fallback
    stride = max(1, len(az) // _SAMPLE)
    a, r = az[::stride], rows[::stride]
    step = _typical_step(a, r, sensor.azimuth_step_rad)
    estimate = int(round(2 * math.pi / step))
    candidates = {fallback, *range(estimate - _CANDIDATES, estimate + _CANDIDATES + 1)}
    candidates = sorted(c for c in candidates if fallback / 2 <= c <= 2 * fallback)
    scores = [coherence(a, r, sensor.n_beams, c) for c in candidates]
    best = candidates[int(np.argmax(scores))]
    if max(scores) < LATTICE_COHERENCE:
        return fallback
    try:
        grid_model(sensor, best)  # within a real sensor's bounds (the decoder checks the same)
    except ValueError:
        return fallback
    return best


def _nearest_rows(el: np.ndarray, beams: np.ndarray) -> np.ndarray:
    """Index of the nearest of ``beams`` (any order) for each elevation."""
    order = np.argsort(beams, kind="stable")
    b = beams[order]
    i = np.clip(np.searchsorted(b, el), 1, len(b) - 1) if len(b) > 1 else np.zeros(len(el), np.int64)
    if len(b) > 1:
        i = np.where(np.abs(el - b[i - 1]) <= np.abs(el - b[i]), i - 1, i)
    return order[i]


def _row_medians(values: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values`` per row (0 for an empty row), from one sort."""
    order = np.lexsort((values, rows))
    v = values[order]
    counts = np.bincount(rows, minlength=n)
    start = np.r_[0, np.cumsum(counts)[:-1]]
    lo = start + np.maximum(counts - 1, 0) // 2
    hi = start + counts // 2
    has = counts > 0
    out = np.zeros(n)
    out[has] = (v[np.minimum(lo[has], len(v) - 1)] + v[np.minimum(hi[has], len(v) - 1)]) / 2
    return out


def fixed_grid(sensor: SensorModel) -> Grid:
    """The sensor's own grid: its column count, rows at the table, firings at cell centres."""
    nb = sensor.n_beams
    return Grid(sensor, sensor.n_azimuth, np.full(nb, 0.5), np.zeros(nb))


def derive_grid(az: np.ndarray, el: np.ndarray, sensor: SensorModel) -> Grid:
    """The grid that follows the returns at azimuths ``az`` and elevations ``el`` (rad): see the
    module doc."""
    nb = sensor.n_beams
    if not len(az):
        return fixed_grid(sensor)
    table = sensor.elevations_rad
    rows = _nearest_rows(el, table)
    offset = np.zeros(nb)
    for _ in range(2):  # offsets from the table's rows, then from the rows the offsets give
        offset = np.clip(_row_medians(el - table[rows], rows, nb), -MAX_OFFSET, MAX_OFFSET)
        offset = np.rint(offset / OFFSET_UNIT) * OFFSET_UNIT
        rows = _nearest_rows(el, table + offset)
    columns = lattice_columns(az, rows, sensor)
    u = (az + math.pi) * columns  # 2 pi x the position in columns
    c = np.bincount(rows, np.cos(u), nb)
    s = np.bincount(rows, np.sin(u), nb)
    phase = np.where(np.hypot(c, s) > 0, np.mod(np.arctan2(s, c) / (2 * math.pi), 1.0), 0.5)
    phase = np.mod(np.rint(phase * PHASE_LEVELS), PHASE_LEVELS) / PHASE_LEVELS
    return Grid(sensor, columns, phase, offset)
