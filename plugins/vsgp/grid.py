"""The scan's own grid and its tiles: where VSGP's cells are, and which local GP owns each.

**Firing-anchored columns.** The sensor model's range image has column ``k`` centred at
``-pi + (k + 0.5) * step``; a real sensor fires wherever its encoder happens to be, and each
laser at its own azimuth offset. A decoder that puts its points on fixed cell centres moves
with where the firings fall against them: on a held-out 16-beam cave whose rays fell on the
cell edges VSGP covered 0.455 of the returns, 0.998 once the scan was rotated by half a step
(issue 25). So each beam carries its *phase* -- the circular mean of its returns' positions
within a column, one byte -- and the grid of beam ``b`` is centred at
``-pi + (k + phase_b) * step``: rotating the scan rotates the phases with it and nothing else.
The circular mean (not the plain mean) because returns at phase 0.02 and 0.98 are neighbours.

**Tiles.** One GP over a 64-beam scan needs thousands of inducing points, and every cell then
costs ``M`` kernel entries and ``M^2`` for its variance. Local GPs (paper 000's reference [19])
bound both: beams are grouped into *bands* of at most :data:`BAND_BEAMS` (the elevation
lengthscale is one beam spacing, so the RQ kernel between beams 16 apart is below 1 % of the
prior), azimuth into equal *sectors* holding about ``tile_points`` inducing points each. Each
tile has its own hyper-parameters and inducing points; neighbouring sectors are blended over a
few columns at each seam (:func:`blend_weights`). Everything here follows from the sensor, the
payload's counts and its hyper-parameters, so an encoder and a decoder derive the same tiling.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lwbench import RangeImage, SensorModel
from lwbench.geometry import spherical

__all__ = [
    "BAND_BEAMS",
    "MAX_TILES",
    "MIN_SECTOR_COLS",
    "PHASE_LEVELS",
    "Tiling",
    "beam_phases",
    "phase_codes",
    "phases_of",
    "project_anchored",
    "column_azimuths",
    "blend_width",
    "blend_weights",
    "HALO_LS",
    "HALO_ROWS",
    "halo_cols",
    "halo_members",
]

#: Beams per band: at 16 beam spacings the RQ kernel (alpha = 1, lengthscale one spacing) is
#: 1/129 of its peak, so a band's GP loses little by ignoring the beams of the next band.
BAND_BEAMS = 16
#: Phase resolution: 1/256 of a column step (one byte per beam).
PHASE_LEVELS = 256


def beam_phases(rows: np.ndarray, az: np.ndarray, sensor: SensorModel) -> np.ndarray:
    """Per beam, the circular mean of its returns' position within a column, in ``[0, 1)``;
    0.5 (the sensor's own cell centre) for a beam with no return."""
    frac = np.mod((az + math.pi) / sensor.azimuth_step_rad, 1.0) * (2 * math.pi)
    s = np.bincount(rows, np.sin(frac), minlength=sensor.n_beams)
    c = np.bincount(rows, np.cos(frac), minlength=sensor.n_beams)
    n = np.bincount(rows, minlength=sensor.n_beams)
    phase = np.mod(np.arctan2(s, c) / (2 * math.pi), 1.0)
    return np.where((n > 0) & (np.hypot(s, c) > 1e-9 * np.maximum(n, 1)), phase, 0.5)


def phase_codes(phase: np.ndarray) -> np.ndarray:
    """Phases in ``[0, 1)`` -> one byte each (``phases_of`` inverts it to the code's centre)."""
    return np.clip(np.floor(np.asarray(phase) * PHASE_LEVELS), 0, PHASE_LEVELS - 1).astype(np.uint8)


def phases_of(codes: np.ndarray) -> np.ndarray:
    return (np.asarray(codes, dtype=np.float64) + 0.5) / PHASE_LEVELS


def project_anchored(points: np.ndarray, sensor: SensorModel) -> tuple[RangeImage, np.ndarray]:
    """The scan on its firing-anchored grid: the range image (nearest return per cell, the
    sensor's range window) and each beam's phase code.

    Beam ``b``'s returns are turned about the vertical axis by ``(0.5 - phase_b)`` steps and
    projected with the sensor's own rule, so column ``k`` of beam ``b`` holds the returns
    nearest ``-pi + (k + phase_b) * step`` (a turn about the axis keeps a return's beam)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return sensor.project(pts), phase_codes(np.full(sensor.n_beams, 0.5))
    r, az, el = spherical(pts)
    beams = sensor.elevations_rad
    rows = np.searchsorted((beams[1:] + beams[:-1]) / 2, el)  # the nearest beam, as SensorModel.cells
    ok = (r >= sensor.min_range) & (r <= sensor.max_range)
    codes = phase_codes(beam_phases(rows[ok], az[ok], sensor))
    turn = (0.5 - phases_of(codes))[rows] * sensor.azimuth_step_rad
    c, s = np.cos(turn), np.sin(turn)
    turned = np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1], pts[:, 2]], axis=1)
    return sensor.project(turned), codes


def column_azimuths(sensor: SensorModel, phase: float, cols: np.ndarray | float) -> np.ndarray:
    """Azimuth (rad) of (possibly fractional) columns of a beam with this phase."""
    return -math.pi + (np.asarray(cols, dtype=np.float64) + phase) * sensor.azimuth_step_rad


@dataclass(frozen=True)
class Tiling:
    """Bands of consecutive beams x equal azimuth sectors; tile ``t = band * n_sectors + sector``."""

    n_beams: int
    n_cols: int
    n_bands: int
    n_sectors: int

    @property
    def n_tiles(self) -> int:
        return self.n_bands * self.n_sectors

    def band_rows(self, band: int) -> tuple[int, int]:
        return (band * self.n_beams) // self.n_bands, ((band + 1) * self.n_beams) // self.n_bands

    def sector_cols(self, sector: int) -> tuple[int, int]:
        return (sector * self.n_cols) // self.n_sectors, ((sector + 1) * self.n_cols) // self.n_sectors

    def tile(self, t: int) -> tuple[int, int]:
        """``(band, sector)`` of tile ``t``."""
        return divmod(t, self.n_sectors)

    @property
    def min_sector_cols(self) -> int:
        return self.n_cols // self.n_sectors

    @staticmethod
    def bands_for(n_beams: int) -> int:
        return max(1, math.ceil(n_beams / BAND_BEAMS))

    @classmethod
    def plan(cls, sensor: SensorModel, num_inducing: int, tile_points: int) -> Tiling:
        """The tiling for ``num_inducing`` points: sectors hold about ``tile_points`` each
        (``tile_points = 0``: one GP over the whole scan, the paper's model). A sector is at
        least :data:`MIN_SECTOR_COLS` columns wide."""
        n_beams, n_cols = sensor.shape
        if tile_points <= 0:
            return cls(n_beams, n_cols, 1, 1)
        bands = cls.bands_for(n_beams)
        per_band = num_inducing / bands
        sectors = int(min(max(1, round(per_band / tile_points)), max(1, n_cols // MIN_SECTOR_COLS), MAX_TILES // bands))
        return cls(n_beams, n_cols, bands, sectors)


#: Tiles one scan may have (each is a GP the decoder factorizes and evaluates in turn, ~0.5-1 ms
#: of bookkeeping each): 2x what a 64-beam scan at 16,000 inducing points takes (124).
MAX_TILES = 256
#: The narrowest sector, in columns: a seam's blend takes up to a quarter of it on each side.
MIN_SECTOR_COLS = 16


def blend_width(ls_cols_a: float, ls_cols_b: float, tiling: Tiling) -> int:
    """Columns blended on each side of the seam between two sectors: half the shorter
    azimuth lengthscale (the scale over which either GP's prediction changes), at least one
    column and at most a quarter of the narrowest sector. 0 when there is only one sector."""
    if tiling.n_sectors == 1:
        return 0
    w = int(round(0.5 * min(ls_cols_a, ls_cols_b)))
    return max(1, min(w, tiling.min_sector_cols // 4))


def blend_weights(x: np.ndarray, c0: int, c1: int, w_lo: int, w_hi: int) -> np.ndarray:
    """Weight of a sector ``[c0, c1)`` at (unwrapped) positions ``x`` in columns (a column's
    centre is ``k + 0.5``): 1 inside, ramping linearly to 0 over ``w`` columns either side of
    each seam, so that the weights of two neighbours sum to 1 across it (``w_lo`` at ``c0``,
    ``w_hi`` at ``c1``)."""
    x = np.asarray(x, dtype=np.float64)
    lo = np.ones_like(x) if w_lo == 0 else np.clip((x - (c0 - w_lo)) / (2 * w_lo), 0.0, 1.0)
    hi = np.ones_like(x) if w_hi == 0 else np.clip(((c1 + w_hi) - x) / (2 * w_hi), 0.0, 1.0)
    return np.minimum(lo, hi)


#: Neighbouring tiles' inducing points a tile's GP also holds: those within this many of its
#: azimuth lengthscales of its sector, and (with several bands) on the :data:`HALO_ROWS` beams
#: beyond its band. A GP with inducing points on one side only of a seam loses its certainty
#: there: without halos the variance filter dropped 55 % of the returns in the columns next
#: to each seam on the sim tunnel (4 sectors), and the means of two sectors disagreed by 25 cm.
#: Sim tunnel (50 frames) 1 / 1.5 / 2 lengthscales: 7.88 / 7.64 / 7.55 cm RMSD; KITTI 00 frame 0
#: at 16,000 points: 0.74 / 0.83 / 0.85 m; the tile's GP grows with the halo (cost ~ its size^2).
HALO_LS = 1.5
HALO_ROWS = 2


def halo_cols(ls_az: float, col_step: float, tiling: Tiling) -> int:
    """Columns a tile's halo reaches beyond its sector (0 with one sector: nothing to reach)."""
    if tiling.n_sectors == 1:
        return 0
    return int(min(math.ceil(HALO_LS * ls_az / col_step), tiling.min_sector_cols))


def halo_members(
    tiling: Tiling, t: int, tile_of: np.ndarray, rows: np.ndarray, colpos: np.ndarray, reach: int
) -> np.ndarray:
    """Indices of the other tiles' inducing points (``tile_of``, beam ``rows``, column position
    ``colpos`` in ``[0, n_cols)``) that tile ``t``'s GP also holds (see :data:`HALO_LS`)."""
    band, sector = tiling.tile(t)
    r0, r1 = tiling.band_rows(band)
    c0, c1 = tiling.sector_cols(sector)
    if tiling.n_bands > 1:
        row_ok = (rows >= r0 - HALO_ROWS) & (rows < r1 + HALO_ROWS)
    else:
        row_ok = np.ones(len(rows), dtype=bool)
    if tiling.n_sectors > 1:
        shifted = np.mod(colpos - c0, tiling.n_cols)
        width = c1 - c0
        dist = np.where(shifted < width, 0.0, np.minimum(shifted - width, tiling.n_cols - shifted))
        col_ok = dist <= reach
    else:
        col_ok = np.ones(len(rows), dtype=bool)
    return np.flatnonzero(row_ok & col_ok & (tile_of != t))
