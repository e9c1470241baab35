"""Base side: predict every tile's occupancy surface on the scan's grid, blend the seams, keep
the occupied part.

Each tile's GP is evaluated exactly on every ``stride``-th column of its sector (widened by the
seam blend) and interpolated in between -- cubic for the mean, linear for the variance, which
only feeds a threshold: the posterior varies over the azimuth lengthscale, tens of columns
(``stride=0``, auto: ``ls_az / (12 * column step)``; error < 1 mm against the exact prediction,
see tests). Neighbouring sectors' predictions are blended linearly over the seam
(``grid.blend_weights``), the variance as a share of each tile's prior variance, and the paper's
variance rule (§IV-B) keeps the cells the model is sure of.

**Bounded.** The work a payload asks for -- kernel entries, every cell's ``M_t^2`` variance
solve, every tile's ``M_t^3 / 3`` factorization -- is counted before anything is evaluated
(:func:`plan_decode`). If the automatic strides would exceed :data:`WORK_BUDGET`, the strides
grow (the decode grid adapts) until it fits; a payload that cannot fit even then, or a
requested ``stride`` that does not, is refused with a ``PayloadError``. The encoder runs the
same plan on what it wrote (``VSGPCodec.encode``), so it never writes a payload its decoder
refuses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy.interpolate import CubicSpline

from lwbench import MAX_WORK, PayloadError, SensorModel
from lwbench.geometry import cartesian

from .gp import Hyper, KernelTables, Predictor
from .grid import Tiling, blend_weights, blend_width, phases_of
from .residuals import apply_residuals, clamp_prediction, slot_shift, unpack_residuals
from .tiles import gather_points, tile_members
from .values import to_range, value_noise
from .wire import Body

__all__ = [
    "DecodeConfig",
    "DecodePlan",
    "plan_decode",
    "auto_stride",
    "variance_mask",
    "reconstruct",
    "reconstruct_residual",
    "GridPrediction",
    "predict_grid",
    "grid_points",
    "query_rows",
    "FLOPS_PER_UNIT",
    "WORK_BUDGET",
    "fits_exactly",
    "decodable",
]

#: Multiply-adds of a triangular solve or factorization that cost as much as one kernel entry
#: (an RQ transform with a log and an exp, the work unit of ``lwbench.MAX_WORK``): measured here
#: with one thread, a float64 entry 3.6 ns, a solve's multiply-add 0.04-0.05 ns (M = 128-512).
FLOPS_PER_UNIT = 64
#: The variance is evaluated on every this-many-th column the mean is (see plan_decode).
VAR_STRIDE_FACTOR = 4
#: Work units of a kernel entry with ``alpha = 1`` (a reciprocal instead of a log and an exp):
#: 0.84 ns against 3.6 ns measured (float64, one thread).
RECIPROCAL_ENTRY = 0.25
#: The work one decode may take, in kernel entries: 1.25 x ``lwbench.MAX_WORK``. Measured here
#: (one thread, shared machine): 3-9 ns of CPU per unit on real payloads (0.39 s for 9.4e7
#: units: KITTI 00 frame 0 at 16,000 inducing points); the hand-made worst payloads the bounds
#: admit (tools/vsgp_fuzz.py) stay near half a second -- under the fuzz contract's 1 s.
WORK_BUDGET = 5 * MAX_WORK // 4
#: Multiply-adds of a tile's Cholesky factorization and solve per work unit: measured 0.21 /
#: 0.14 / 0.10 / 0.08 ns a multiply-add at M = 128 / 256 / 512 / 1024 (the per-tile units below
#: cover the small-M overhead).
CHOL_FLOPS_PER_UNIT = 32
#: Units each tile costs whatever its size (its Python bookkeeping, ~0.5-1 ms measured): a payload of 1,024
#: empty tiles is bounded too.
TILE_UNITS = 100_000
_BLOCK_ENTRIES = 1 << 21  # kernel entries per block of rows (float64: 16 MB)


@dataclass(frozen=True)
class DecodeConfig:
    upsample: int = 1
    k_m: float = 0.1
    k_std: float = 0.0
    v_floor: float = 0.1
    stride: int = 0


@dataclass
class TilePlan:
    rows: np.ndarray  # query-row indices in this tile's band
    cols: np.ndarray  # unwrapped fine columns predicted (all of them, interpolated or exact)
    eval_idx: np.ndarray  # indices into ``cols`` where the mean is evaluated exactly
    var_idx: np.ndarray  # ... and the variance (a subset of ``eval_idx``)
    weights: np.ndarray  # blend weight per column of ``cols``


@dataclass
class DecodePlan:
    tiles: list[TilePlan]
    work: int
    strides: list[int]
    factor: int  # how much the automatic strides were widened to fit the budget (1: not at all)


def query_rows(sensor: SensorModel, upsample: int) -> tuple[np.ndarray, np.ndarray]:
    """Elevation of every query row and the beam below it (its band, its phase). The finer grid
    contains the sensor's own beams, so an up-sampled decode is a superset of the plain one."""
    beams = sensor.elevations_rad
    if upsample == 1 or len(beams) == 1:
        return beams, np.arange(len(beams))
    pos = np.linspace(0, len(beams) - 1, (len(beams) - 1) * upsample + 1)
    return np.interp(pos, np.arange(len(beams)), beams), np.minimum(np.floor(pos + 1e-9).astype(int), len(beams) - 1)


def auto_stride(h: Hyper, col_step: float) -> int:
    return max(1, int(h.ls_az / (12 * col_step)))


def _tile_columns(tiling: Tiling, sector: int, widths: tuple[int, int], upsample: int) -> np.ndarray:
    if tiling.n_sectors == 1:
        return np.arange(tiling.n_cols * upsample)
    c0, c1 = tiling.sector_cols(sector)
    return np.arange((c0 - widths[0]) * upsample, (c1 + widths[1]) * upsample)


def _evaluated(n: int, stride: int) -> np.ndarray:
    idx = np.arange(0, n, stride)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def _seam_widths(body: Body, tiling: Tiling, col_step: float) -> list[tuple[int, int]]:
    out = []
    for t in range(tiling.n_tiles):
        band, s = tiling.tile(t)
        left = band * tiling.n_sectors + (s - 1) % tiling.n_sectors
        right = band * tiling.n_sectors + (s + 1) % tiling.n_sectors
        ls = [body.tiles[i].hyper[0] / col_step for i in (left, t, right)]
        out.append((blend_width(ls[0], ls[1], tiling), blend_width(ls[1], ls[2], tiling)))
    return out


def plan_decode(body: Body, sensor: SensorModel, cfg: DecodeConfig) -> DecodePlan:
    """What each tile evaluates, and the work it costs; strides adapted to :data:`WORK_BUDGET`.

    The mean is evaluated every ``ls_az / 12`` columns (``auto_stride``), the variance -- which
    only feeds a threshold and costs ``M_t^2`` a cell -- on every ``VAR_STRIDE_FACTOR``-th of
    those (about four per lengthscale); ``stride > 0`` evaluates both on every ``stride``-th."""
    tiling = body.tiling
    u = cfg.upsample
    fine_step = sensor.azimuth_step_rad / u
    _, beam_of = query_rows(sensor, u)
    widths = _seam_widths(body, tiling, sensor.azimuth_step_rad)
    pts = gather_points(body, sensor)
    base, layouts, fixed = [], [], 0
    for t, tile in enumerate(body.tiles):
        band, sector = tiling.tile(t)
        r0, r1 = tiling.band_rows(band)
        rows = np.flatnonzero((beam_of >= r0) & (beam_of < r1))
        cols = _tile_columns(tiling, sector, widths[t], u)
        m_t = len(tile_members(body, sensor, pts, t))
        entry = RECIPROCAL_ENTRY if tile.hyper[2] == 1.0 else 1.0
        fixed += TILE_UNITS + int(entry * m_t * m_t) + m_t**3 // (3 * CHOL_FLOPS_PER_UNIT) + len(rows) * len(cols)
        base.append(cfg.stride if cfg.stride > 0 else auto_stride(Hyper(*tile.hyper), fine_step))
        layouts.append((rows, cols, m_t, entry))
    every = 1 if cfg.stride > 0 else VAR_STRIDE_FACTOR

    def sets(n: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
        if n == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        mean_at = _evaluated(n, min(n, stride))
        return mean_at, np.unique(np.append(mean_at[::every], mean_at[-1]))

    def work(factor: int) -> int:
        total = fixed
        for (rows, cols, m_t, entry), s in zip(layouts, base, strict=True):
            mean_at, var_at = sets(len(cols), s * factor)
            total += len(rows) * (int(entry * len(mean_at) * m_t) + len(var_at) * (m_t * m_t) // FLOPS_PER_UNIT)
        return total

    factor = 1
    while (
        work(factor) > WORK_BUDGET
        and cfg.stride == 0
        and any(s * factor < len(c) for (_, c, _, _), s in zip(layouts, base, strict=True))
    ):
        factor *= 2
    total = work(factor)
    if total > WORK_BUDGET:
        raise PayloadError(
            f"vsgp payload: the decode grid's kernel would take {total:,} evaluations, more than {WORK_BUDGET:,}"
        )
    plans, strides = [], []
    for t, ((rows, cols, _, _), s) in enumerate(zip(layouts, base, strict=True)):
        stride = min(max(1, len(cols)), s * factor)
        band, sector = tiling.tile(t)
        c0, c1 = tiling.sector_cols(sector)
        w = np.ones(len(cols)) if tiling.n_sectors == 1 else blend_weights((cols + 0.5) / u, c0, c1, *widths[t])
        mean_at, var_at = sets(len(cols), stride)
        plans.append(TilePlan(rows, cols, mean_at, var_at, w))
        strides.append(stride)
    return DecodePlan(plans, total, strides, factor)


def _interpolate(values: np.ndarray, eval_idx: np.ndarray, n: int, cubic: bool) -> np.ndarray:
    if len(eval_idx) == n:
        return values
    x = np.arange(n)
    if cubic and len(eval_idx) >= 4:
        return CubicSpline(eval_idx, values, axis=1)(x)
    j = np.clip(np.searchsorted(eval_idx, x, side="right") - 1, 0, len(eval_idx) - 2)
    frac = (x - eval_idx[j]) / (eval_idx[j + 1] - eval_idx[j])
    return values[:, j] * (1 - frac) + values[:, j + 1] * frac


def _predict_tile(
    tile_z: torch.Tensor,
    tile_u: torch.Tensor,
    h: Hyper,
    u_noise: float,
    az: torch.Tensor,
    el: torch.Tensor,
    var_sub: torch.Tensor,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean on every column of ``az``, variance on the columns ``var_sub`` of it."""
    pred = Predictor(tile_z, tile_u, h, u_noise)
    tables = KernelTables(az, el, pred.z, h)
    block = max(1, _BLOCK_ENTRIES // max(1, len(az) * max(1, len(tile_u))))
    means, variances = [], []
    for r0 in range(0, len(el), block):
        k = tables.grid(r0, r0 + block)
        means.append(pred.mean(k).cpu().numpy())
        variances.append(pred.variance(k[:, var_sub]).cpu().numpy())
    return np.concatenate(means), np.concatenate(variances)


def variance_mask(var: np.ndarray, k_m: float, k_std: float, floor: float = 0.0) -> np.ndarray:
    """Cells judged occupied: ``var <= max(V_th, floor)``, ``V_th = k_m * mean(var) + k_std * std(var)``
    (paper §IV-B), ``var`` as a share of each tile's prior variance. ``floor``: a scan with almost
    no free space has no high-variance mode, and a threshold relative to the grid's own statistics
    would then cut into the occupied surface."""
    return var <= max(k_m * var.mean() + k_std * var.std(), floor)


@dataclass
class GridPrediction:
    """The decoded surface on the query grid, before it becomes points: the range of every
    cell, which cells the variance rule keeps, and where each row and column points."""

    ranges: np.ndarray  # (rows, cols) metres
    keep: np.ndarray  # (rows, cols) bool
    el_rows: np.ndarray  # (rows,) elevation rad
    beam_of: np.ndarray  # (rows,) the beam below each row (its phase)
    fine_az: np.ndarray  # (cols,) azimuth of each column's centre at phase 0.5


def predict_grid(
    body: Body, sensor: SensorModel, cfg: DecodeConfig, device: torch.device, timings: dict[str, float] | None = None
) -> GridPrediction:
    """Every tile's prediction on the (``upsample``-times finer) grid, blended, with the
    variance rule applied: what the encoder also needs to know which cells its decoder gets
    wrong (``residuals.py``)."""
    t0 = time.perf_counter()
    u = cfg.upsample
    el_rows, beam_of = query_rows(sensor, u)
    n_cols = sensor.n_azimuth * u
    fine_az = sensor.azimuths_rad()[0] + np.arange(n_cols) * sensor.azimuth_step_rad / u
    if body.num_inducing == 0:
        shape = (len(el_rows), n_cols)
        return GridPrediction(np.zeros(shape), np.zeros(shape, dtype=bool), el_rows, beam_of, fine_az)
    plan = plan_decode(body, sensor, cfg)
    f_acc = np.zeros((len(el_rows), n_cols))
    v_acc = np.zeros((len(el_rows), n_cols))
    pts = gather_points(body, sensor)
    f_all = np.concatenate([t.value + t.offset for t in body.tiles])  # every point's occupancy
    for t, (tile, tp) in enumerate(zip(body.tiles, plan.tiles, strict=True)):
        if not len(tp.rows) or not len(tp.cols):
            continue
        h = Hyper(*tile.hyper)
        wrapped = np.mod(tp.cols, n_cols)
        members = tile_members(body, sensor, pts, t)
        if len(members) == 0:
            f_t, v_t = np.zeros((len(tp.rows), len(tp.cols))), np.ones((len(tp.rows), len(tp.cols)))
        else:
            z = torch.as_tensor(
                np.stack([pts.az[members], sensor.elevations_rad[pts.beam[members]]], axis=1),
                dtype=torch.float64,
                device=device,
            )
            u_t = torch.as_tensor(f_all[members] - tile.offset, dtype=torch.float64, device=device)
            az = torch.as_tensor(fine_az[wrapped[tp.eval_idx]], dtype=torch.float64, device=device)
            el = torch.as_tensor(el_rows[tp.rows], dtype=torch.float64, device=device)
            var_sub = torch.as_tensor(np.searchsorted(tp.eval_idx, tp.var_idx), device=device)
            mean_e, var_e = _predict_tile(z, u_t, h, value_noise(h, sensor.azimuth_step_rad), az, el, var_sub)
            f_t = tile.offset + _interpolate(mean_e, tp.eval_idx, len(tp.cols), cubic=True)
            v_t = _interpolate(var_e, tp.var_idx, len(tp.cols), cubic=False) / h.outputscale
        f_acc[np.ix_(tp.rows, wrapped)] += tp.weights * f_t
        v_acc[np.ix_(tp.rows, wrapped)] += tp.weights * v_t
    r = to_range(f_acc, body.transform, body.r_oc)
    r_max = min(body.r_oc, sensor.max_range)
    keep = variance_mask(v_acc, cfg.k_m, cfg.k_std, cfg.v_floor) & (r >= sensor.min_range) & (r < r_max)
    if timings is not None:
        timings["predict"] = time.perf_counter() - t0
    return GridPrediction(r, keep, el_rows, beam_of, fine_az)


def grid_points(
    pred: GridPrediction,
    body: Body,
    sensor: SensorModel,
    rows: np.ndarray,
    cols: np.ndarray,
    ranges: np.ndarray,
    shift: np.ndarray | float = 0.0,
) -> np.ndarray:
    """Points at cells ``(rows, cols)`` of the prediction's grid with these ranges, each
    ``shift`` azimuth steps from its cell's anchored centre."""
    phase = phases_of(body.phase_codes)[pred.beam_of[rows]]
    az_out = pred.fine_az[cols] + (phase - 0.5 + shift) * sensor.azimuth_step_rad
    return cartesian(ranges, az_out, pred.el_rows[rows])


def reconstruct(
    body: Body, sensor: SensorModel, cfg: DecodeConfig, device: torch.device, timings: dict[str, float] | None = None
) -> np.ndarray:
    """Decoded cloud (float32 ``(K, 3)``, sensor frame)."""
    pred = predict_grid(body, sensor, cfg, device, timings)
    t1 = time.perf_counter()
    rows, cols = np.nonzero(pred.keep)
    pts = grid_points(pred, body, sensor, rows, cols, pred.ranges[rows, cols])
    if timings is not None:
        timings["sampling"] = time.perf_counter() - t1
    return pts.astype(np.float32)


def reconstruct_residual(
    body: Body, section: bytes, sensor: SensorModel, device: torch.device, timings: dict[str, float] | None = None
) -> np.ndarray:
    """Decoded cloud of a payload with a residual layer (``residuals.py``): a point per slot,
    its range the GP's prediction corrected by the slot's residual. The prediction is the
    default decoder's on the sensor's own grid -- the one the encoder measured its residuals
    against -- whatever this decoder's ``upsample``, ``stride`` or variance rule."""
    res = unpack_residuals(section, sensor)
    pred = predict_grid(body, sensor, DecodeConfig(), device, timings)
    t1 = time.perf_counter()
    rows, cols = np.divmod(res.slots.cell, sensor.n_azimuth)
    ranges = apply_residuals(
        clamp_prediction(pred.ranges[rows, cols], sensor), res.coded, res.k, res.q, sensor, res.absolute
    )
    pts = grid_points(pred, body, sensor, rows, cols, ranges, slot_shift(res.slots))
    if timings is not None:
        timings["sampling"] = time.perf_counter() - t1
    return pts.astype(np.float32)


def fits_exactly(body: Body, sensor: SensorModel) -> bool:
    """Whether the default decoder takes this body at its automatic strides (not widened)."""
    try:
        return plan_decode(body, sensor, DecodeConfig()).factor == 1 if body.num_inducing else True
    except PayloadError:
        return False


def decodable(body: Body, sensor: SensorModel, cfg: DecodeConfig | None = None) -> int:
    """The work a decoder will spend on this body (raises ``PayloadError`` if it would refuse)."""
    return plan_decode(body, sensor, cfg or DecodeConfig()).work if body.num_inducing else 0
