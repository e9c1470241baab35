"""Scout side: occupancy surface, tiles, inducing layout, hyper-parameters, q(u) -- per tile.

The steps, each timed by the codec:

1. *projection* -- the scan onto its firing-anchored range image (``grid.project_anchored``);
   occupied cells are those with a return closer than ``r_oc``; their occupancy is
   ``f = r_oc - r`` (paper §IV-A, ``transform="linear"``) or ``f = 1/r`` (``"inverse"``: a plane's
   inverse range is a smooth function of direction, so walls and ground far away stay smooth
   where ``r`` itself bends sharply).
2. *layout* -- the tiling (``grid.Tiling.plan``) and ``M`` inducing inputs on the occupied part,
   one row per beam: along each beam they sit at equal quantiles of a weight mixing uniform
   density (the paper's "evenly distributed", share ``1 - adapt``) with the occupancy's
   variation (share ``adapt``), so range edges get more points than flat walls (measured: 14.0
   -> 10.8 cm RMSD on the sim tunnel at M=500). Tiles get points in proportion to their weight.
3. *refine* -- per tile, hyper-parameters start from the sensor's geometry (:func:`initial_hyper`)
   or, with a warm start, from the previous frame's; optionally (``steps > 0``) Adam steps on
   Titsias' collapsed bound over a seeded subsample, stopping when the bound stops improving.
4. *fit* -- per tile, the closed-form optimal q(u) on the tile's occupied cells and a halo one
   lengthscale wide around it, every ``stride``-th column (``stride`` from the lengthscale:
   about :data:`FIT_COLUMNS_PER_LS` fitted columns per lengthscale); its mean at the inducing
   inputs is what the payload carries.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from lwbench import ParameterError, SensorModel

from .gp import Hyper, chord_sq, posterior_inducing_mean, rq_cross, rq_from_sqdist
from .grid import HALO_ROWS, Tiling, halo_cols, project_anchored
from .tiles import Points, gather_points, tile_members
from .values import LS_FACTOR_AZ, occupancy, to_range
from .wire import MAX_TILE_INDUCING, Body, TileModel, dequantize_azimuth, quantize_azimuth

__all__ = [
    "FitConfig",
    "FitResult",
    "LS_FACTOR_AZ",
    "FIT_COLUMNS_PER_LS",
    "occupancy",
    "to_range",
    "layout_inducing",
    "initial_hyper",
    "fit_scan",
    "fit_stride",
    "empty_body",
]

#: The smallest tiles ``_layout`` shrinks to (points a tile, before halos).
MIN_TILE_POINTS = 16
#: Fit bins per azimuth lengthscale: q(u) changes over a lengthscale, and a bin carries the sums
#: of every cell in it (:func:`_tile_bins`), so a few bins per lengthscale lose nothing: sim
#: tunnel, 50 frames, 12 / 8 / 6 bins a lengthscale: 8.53 / 8.53 / 8.54 cm RMSD.
FIT_COLUMNS_PER_LS = 6.0


@dataclass(frozen=True)
class FitConfig:
    num_inducing: int | None = None
    cells_per_point: float = 100.0
    tile_points: int = 128
    adapt: float = 0.7
    noise_std: float = 0.05
    transform: str = "linear"
    center: bool = True
    r_oc: float | None = None
    steps: int = 0
    lr: float = 0.1
    tol: float = 1e-3
    subsample: int = 2048
    fit_stride: int = 0
    learn_inducing: bool = False
    seed: int = 0


@dataclass
class FitResult:
    body: Body
    steps_run: int = 0
    bounds: list[float] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)


def occupancy_weights(occ: np.ndarray, f: np.ndarray, adapt: float) -> np.ndarray:
    """Layout weight of every cell: ``(1 - adapt)`` spread evenly over the occupied cells plus
    ``adapt`` in proportion to ``|df|`` along the beam (each step capped at 1.5 standard
    deviations of ``f``, so one depth edge does not take every point, and shared by the cells on
    both of its sides)."""
    w = np.zeros(occ.shape)
    n = int(occ.sum())
    if n == 0:
        return w
    both = occ[:, 1:] & occ[:, :-1]
    step = np.minimum(np.where(both, np.abs(np.diff(f, axis=1)), 0.0), 1.5 * float(f[occ].std()) + 1e-12)
    dy = np.zeros(occ.shape)  # each step shared by the cells on both sides: a point on each side of an edge
    dy[:, 1:] += step / 2
    dy[:, :-1] += step / 2
    total = dy.sum()
    share = dy / total if total > 0 else np.where(occ, 1.0 / n, 0.0)
    return np.where(occ, (1 - adapt) / n + adapt * share, 0.0)


def _largest_remainder(quota: np.ndarray, cap: np.ndarray, m: int) -> np.ndarray:
    alloc = np.minimum(np.floor(quota).astype(np.int64), cap)
    rest = int(min(m, cap.sum()) - alloc.sum())
    if rest > 0:
        order = np.argsort(-(quota - alloc) + (alloc >= cap) * 1e18, kind="stable")
        alloc[order[:rest]] += 1
    return np.minimum(alloc, cap)


def _segments(cols: np.ndarray, w: np.ndarray, a: int) -> np.ndarray:
    """Centroids (column positions) of ``a`` contiguous, non-empty runs of a row's cells of
    about equal weight: boundaries where the cumulative weight crosses ``k / a``, pushed apart
    so that every run holds a cell (a heavy depth edge must not leave runs empty)."""
    n = len(cols)
    if a >= n:
        return cols.astype(np.float64)
    cw = np.cumsum(w)
    k = np.arange(1, a)
    b = np.searchsorted(cw, cw[-1] * k / a, side="left") + 1
    b = np.maximum.accumulate(b - k) + k
    b = np.minimum(b, n - a + k)
    starts = np.concatenate([[0], b])
    sizes = np.diff(np.concatenate([starts, [n]]))
    return np.add.reduceat(cols.astype(np.float64), starts) / sizes


def layout_inducing(occ: np.ndarray, w: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``m`` inducing points on the occupied cells of a tile: ``(rows, column positions)``.

    Rows get points in proportion to their total weight (largest remainder); along a row, a
    point per run of cells of equal weight (:func:`_segments`), at the run's centroid."""
    rows, cols = np.nonzero(occ)
    if len(rows) == 0 or m == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    if len(rows) <= m:
        return rows.astype(np.int64), cols.astype(np.float64)
    ww = w[rows, cols]
    n_rows = occ.shape[0]
    row_w = np.bincount(rows, ww, minlength=n_rows)
    row_n = np.bincount(rows, minlength=n_rows)
    quota = row_w / row_w.sum() * m if row_w.sum() > 0 else row_n / len(rows) * m
    alloc = _largest_remainder(quota, row_n, m)
    first = np.concatenate([[0], np.cumsum(row_n)[:-1]])
    out_rows, out_cols = [], []
    for r in np.flatnonzero(alloc):
        sl = slice(first[r], first[r] + row_n[r])
        pos = _segments(cols[sl], np.maximum(ww[sl], 1e-12), int(alloc[r]))
        out_rows.append(np.full(len(pos), r, np.int64))
        out_cols.append(pos)
    return np.concatenate(out_rows), np.concatenate(out_cols)


def initial_hyper(
    sensor: SensorModel, rows: tuple[int, int], n_occupied: int, m: int, y: np.ndarray, noise_var: float
) -> Hyper:
    """A tile's hyper-parameters from the sensor's geometry, before any data-driven step.

    Elevation: one inducing row per beam, so the lengthscale is the band's beam spacing
    (adjacent beams often see different surfaces -- floor vs wall -- and must not be smoothed
    together). Azimuth: ``LS_FACTOR_AZ`` x the mean spacing of the inducing points along the
    occupied part of a beam; shorter lengthscales leave gaps that fall back to the prior mean,
    longer ones smooth edges away (factor chosen by the sweep in ``docs/vsgp.md``). The
    outputscale is the second moment of ``f - offset`` (the prior's variance). All values are
    rounded to float32, as the payload carries them, so encoder and decoder use the same GP.
    """
    beams = sensor.elevations_rad[rows[0] : rows[1]]
    gaps = np.diff(beams)
    gaps = gaps[gaps > 1e-6]
    beam_step = (
        float(np.median(gaps))
        if len(gaps)
        else (float(np.median(np.diff(sensor.elevations_rad))) if sensor.n_beams > 1 else math.radians(2.0))
    )
    beam_step = max(beam_step, 1e-4)
    n_rows = max(1, rows[1] - rows[0])
    per_beam_cells = n_occupied / n_rows
    per_beam_points = max(1.0, m / n_rows)
    ls_az = LS_FACTOR_AZ * sensor.azimuth_step_rad * max(1.0, per_beam_cells / per_beam_points)
    scale = float(np.mean(np.square(y))) if len(y) else 1.0
    vals = [min(ls_az, 2 * math.pi), beam_step, 1.0, max(scale, 1e-10), max(noise_var, 1e-13)]
    return Hyper(*(float(np.float32(v)) for v in vals))


def fit_stride(h: Hyper, col_step: float, requested: int = 0) -> int:
    """Columns between fitted columns: about :data:`FIT_COLUMNS_PER_LS` per lengthscale."""
    if requested > 0:
        return requested
    return max(1, int(h.ls_az / (FIT_COLUMNS_PER_LS * col_step)))


@dataclass
class _Scan:
    """The projected scan every tile reads from."""

    sensor: SensorModel
    occ: np.ndarray  # (B, C) bool
    f: np.ndarray  # (B, C) occupancy, 0 where free
    r: np.ndarray  # (B, C) range, 0 where free
    w: np.ndarray  # (B, C) layout weight
    col_az: np.ndarray  # (C,) GP azimuth of each column
    row_el: np.ndarray  # (B,) GP elevation of each row


def _tile_bins(
    scan: _Scan, tiling: Tiling, t: int, reach: int, stride: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tile ``t``'s fit data, binned: the occupied cells of the band (+ halo rows) and the sector
    (+ ``reach`` columns) grouped per beam into runs of ``stride`` columns (aligned to multiples of
    ``stride``); per bin its row, mean column position, mean occupancy and cell count.

    Binning instead of keeping every ``stride``-th column: the sums the fit needs
    (``sum_i k_i k_i^T``, ``sum_i k_i y_i``) are those of every cell to second order in
    ``stride / lengthscale`` -- every cell's data enters at a strided fit's cost."""
    band, sector = tiling.tile(t)
    r0, r1 = tiling.band_rows(band)
    c0, c1 = tiling.sector_cols(sector)
    n_b, n_c = scan.occ.shape
    fr0, fr1 = (max(0, r0 - HALO_ROWS), min(n_b, r1 + HALO_ROWS)) if tiling.n_bands > 1 else (r0, r1)
    cols = np.arange(c0 - reach, c1 + reach) if tiling.n_sectors > 1 else np.arange(n_c)
    wrapped = np.mod(cols, n_c)
    first = cols[0] - np.mod(cols[0], stride)
    bin_of = (cols - first) // stride
    n_bins = int(bin_of[-1]) + 1
    rr, cc = np.nonzero(scan.occ[fr0:fr1][:, wrapped])
    key = rr * n_bins + bin_of[cc]
    counts = np.bincount(key, minlength=(fr1 - fr0) * n_bins)
    nz = np.flatnonzero(counts)
    pos = np.bincount(key, cols[cc].astype(np.float64), minlength=len(counts))[nz] / counts[nz]
    ybar = np.bincount(key, scan.f[rr + fr0, wrapped[cc]], minlength=len(counts))[nz] / counts[nz]
    return nz // n_bins + fr0, pos, ybar, counts[nz].astype(np.float64)


def _noise_var(scan: _Scan, core: np.ndarray, cfg: FitConfig, r_oc: float) -> float:
    if cfg.transform == "linear":
        return cfg.noise_std**2
    # The range noise seen through d(1/r)/dr = -1/r^2, at the tile's median range.
    r_med = float(np.median(core)) if len(core) else r_oc
    return (cfg.noise_std / r_med**2) ** 2


def _layout_tile(scan: _Scan, tiling: Tiling, t: int, m_t: int, cfg: FitConfig, r_oc: float) -> TileModel:
    """Phase 1 of a tile: its offset, inducing layout and sensor-derived hyper-parameters."""
    band, sector = tiling.tile(t)
    r0, r1 = tiling.band_rows(band)
    c0, c1 = tiling.sector_cols(sector)
    occ = scan.occ[r0:r1, c0:c1]
    f_core = scan.f[r0:r1, c0:c1][occ]
    offset = float(np.float32(f_core.mean())) if cfg.center and len(f_core) else 0.0
    rows, colpos = layout_inducing(occ, scan.w[r0:r1, c0:c1], m_t)
    az_code = quantize_azimuth(scan.col_az[0] + (colpos + c0) * scan.sensor.azimuth_step_rad)
    noise = _noise_var(scan, scan.r[r0:r1, c0:c1][occ], cfg, r_oc)
    h = initial_hyper(scan.sensor, (r0, r1), len(f_core), max(1, len(rows)), f_core - offset, noise)
    return TileModel(az_code, rows + r0, np.zeros(len(rows)), tuple(h.as_list()), offset)


def _refine_tile(
    scan: _Scan, tiling: Tiling, t: int, tile: TileModel, cfg: FitConfig, device: torch.device, warm: Hyper | None
) -> tuple[int, list[float]]:
    """Hyper-parameter steps on the collapsed bound (``steps > 0``), in place on ``tile``."""
    band, sector = tiling.tile(t)
    r0, r1 = tiling.band_rows(band)
    c0, c1 = tiling.sector_cols(sector)
    occ = scan.occ[r0:r1, c0:c1]
    f_core = scan.f[r0:r1, c0:c1][occ]
    if cfg.steps == 0 or not len(f_core) > len(tile.beam) > 0:
        return 0, []
    from .learn import refine

    z = torch.as_tensor(
        np.stack([dequantize_azimuth(tile.az_code), scan.row_el[tile.beam]], axis=1), dtype=torch.float64, device=device
    )
    rr, cc = np.nonzero(occ)
    rng = np.random.default_rng([cfg.seed, t])
    sub = np.sort(rng.choice(len(rr), size=min(cfg.subsample, len(rr)), replace=False))
    x = torch.as_tensor(
        np.stack([scan.col_az[cc[sub] + c0], scan.row_el[rr[sub] + r0]], axis=1), dtype=torch.float64, device=device
    )
    y = torch.as_tensor(f_core[sub] - tile.offset, dtype=torch.float64, device=device)
    with torch.enable_grad():
        h, z, bounds = refine(x, y, z, warm if warm is not None else Hyper(*tile.hyper), cfg)
    tile.hyper = tuple(h.as_list())
    tile.az_code = quantize_azimuth(z[:, 0].cpu().numpy())
    return max(0, len(bounds) - 1), bounds


def _layout(scan: _Scan, m_req: int, cfg: FitConfig, r_oc: float, phases: np.ndarray) -> Body:
    """Tiling and every tile's layout (phase 1). Tiles shrink (``tile_points`` halves, down to
    :data:`MIN_TILE_POINTS`) until the decoder's work budget admits the payload at its automatic
    strides: a tile's factorization costs its size cubed and each cell's variance its size
    squared, so on dense scans smaller tiles keep every column of the decode exact (KITTI 00 at
    16,000 points, 128 a tile: strides 4-8 where the lengthscale is 4-30 columns, 1.43 m RMSD)."""
    from .decoder import fits_exactly

    sensor = scan.sensor
    tile_points = cfg.tile_points
    while True:
        tiling = Tiling.plan(sensor, max(1, m_req), tile_points)
        tile_w, tile_n = np.zeros(tiling.n_tiles), np.zeros(tiling.n_tiles, np.int64)
        for t in range(tiling.n_tiles):
            band, sector = tiling.tile(t)
            (r0, r1), (c0, c1) = tiling.band_rows(band), tiling.sector_cols(sector)
            tile_w[t] = scan.w[r0:r1, c0:c1].sum()
            tile_n[t] = scan.occ[r0:r1, c0:c1].sum()
        m = min(m_req, int(tile_n.sum()))
        quota = tile_w / tile_w.sum() * m if tile_w.sum() > 0 else np.zeros(tiling.n_tiles)
        alloc = _largest_remainder(quota, tile_n, m)
        tiles = [_layout_tile(scan, tiling, t, int(alloc[t]), cfg, r_oc) for t in range(tiling.n_tiles)]
        body = Body(cfg.transform, r_oc, tiling, phases, tiles)
        smaller = tile_points // 2
        if (
            tile_points == 0
            or smaller < MIN_TILE_POINTS
            or fits_exactly(body, sensor)
            or Tiling.plan(sensor, max(1, m_req), smaller) == tiling
        ):
            return body
        tile_points = smaller


def _fit_tile(scan: _Scan, body: Body, pts: Points, t: int, cfg: FitConfig, device: torch.device) -> np.ndarray:
    """Phase 2 of a tile: q(u) over its own and its halo's inducing points (``tiles.py``) from
    its cells and the halo's; returns the values of its own points."""
    tile = body.tiles[t]
    own = len(tile.az_code)
    if own == 0:
        return np.zeros(0)
    h = Hyper(*tile.hyper)
    members = tile_members(body, scan.sensor, pts, t)
    z = torch.as_tensor(
        np.stack([pts.az[members], scan.row_el[pts.beam[members]]], axis=1), dtype=torch.float64, device=device
    )
    col_step = scan.sensor.azimuth_step_rad
    band, sector = body.tiling.tile(t)
    (r0, r1), (c0, c1) = body.tiling.band_rows(band), body.tiling.sector_cols(sector)
    occ_core = int(scan.occ[r0:r1, c0:c1].sum())
    stride = 1 if occ_core <= 4 * own else fit_stride(h, col_step, cfg.fit_stride)
    reach = halo_cols(h.ls_az, col_step, body.tiling)
    br, bpos, ybar, n = _tile_bins(scan, body.tiling, t, reach, stride)
    row_ids, row_inv = np.unique(br, return_inverse=True)
    az = torch.as_tensor(scan.col_az[0] + bpos * col_step, device=device)
    de2 = ((torch.as_tensor(scan.row_el[row_ids], device=device)[:, None] - z[None, :, 1]) / h.ls_el).square_()
    d2 = chord_sq(az, z[:, 0]).div_(h.ls_az**2).add_(de2[torch.as_tensor(row_inv, device=device)])
    knm = rq_from_sqdist(d2, h.alpha, h.outputscale)
    y = torch.as_tensor(ybar - tile.offset, dtype=torch.float64, device=device)
    u = posterior_inducing_mean(rq_cross(z, z, h), knm, y, h, torch.as_tensor(n, device=device).sqrt_())
    return u[:own].cpu().numpy()


def fit_scan(
    points: np.ndarray, sensor: SensorModel, cfg: FitConfig, device: torch.device, warm: list[Hyper] | None = None
) -> FitResult:
    """Encode one scan into its tiles' inducing points, values and hyper-parameters.

    ``warm``: the previous frame's per-tile hyper-parameters, used as the refinement's starting
    point when the tiling is the same (``steps > 0``); the payload does not depend on anything
    else of the previous frame."""
    t0 = time.perf_counter()
    r_oc = float(np.float32(cfg.r_oc or sensor.max_range))
    image, phases = project_anchored(points, sensor)
    r = image.ranges.astype(np.float64)
    occ = (r > 0) & (r < r_oc)
    f = np.where(occ, occupancy(np.where(occ, r, 1.0), cfg.transform, r_oc), 0.0)
    t1 = time.perf_counter()
    n_occ = int(occ.sum())
    m_req = cfg.num_inducing if cfg.num_inducing is not None else int(math.ceil(n_occ / cfg.cells_per_point))
    if cfg.tile_points == 0 and m_req > MAX_TILE_INDUCING:
        raise ParameterError(
            f"vsgp: one GP over the whole scan (tile_points=0 / mode=paper) holds at most "
            f"{MAX_TILE_INDUCING} inducing points, this scan asks for {m_req}"
        )
    w = occupancy_weights(occ, f, cfg.adapt)
    scan = _Scan(sensor, occ, f, np.where(occ, r, 0.0), w, sensor.azimuths_rad(), sensor.elevations_rad)
    with torch.no_grad():
        body = _layout(scan, m_req, cfg, r_oc, phases)
        t2 = time.perf_counter()
        if warm is not None and len(warm) != body.tiling.n_tiles:
            warm = None
        steps, bounds = 0, []
        for t, tile in enumerate(body.tiles):
            s, b = _refine_tile(scan, body.tiling, t, tile, cfg, device, warm[t] if warm else None)
            steps, bounds = max(steps, s), bounds + b
        t3 = time.perf_counter()
        pts = gather_points(body, sensor)
        for t, tile in enumerate(body.tiles):
            tile.value = _fit_tile(scan, body, pts, t, cfg, device)
    timings = {"projection": t1 - t0, "layout": t2 - t1, "refine": t3 - t2, "fit": time.perf_counter() - t3}
    return FitResult(body, steps, bounds, timings)


def empty_body(points: np.ndarray, sensor: SensorModel, cfg: FitConfig) -> FitResult:
    """A body with no inducing point -- only the beams' phases and one empty GP, which predicts
    nothing: the residual layer's control (``predictor=none``), which measures what the GP
    surface is worth as a predictor against coding every range on its own."""
    t0 = time.perf_counter()
    r_oc = float(np.float32(cfg.r_oc or sensor.max_range))
    _, phases = project_anchored(points, sensor)
    tile = TileModel(np.zeros(0, np.uint16), np.zeros(0, np.int64), np.zeros(0), (1.0, 1.0, 1.0, 1.0, 1e-4), 0.0)
    body = Body(cfg.transform, r_oc, Tiling.plan(sensor, 1, 0), phases, [tile])
    return FitResult(body, timings={"projection": time.perf_counter() - t0})
