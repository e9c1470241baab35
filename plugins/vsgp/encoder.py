"""Scout side: occupancy surface, inducing-point layout, hyper-parameter refinement, q(u).

The steps, each timed by the codec:

1. *projection* -- the scan onto the sensor's range image; occupied cells are those with a
   return closer than ``r_oc``; their occupancy is ``f = r_oc - r`` (paper §IV-A).
2. *layout* -- ``M`` inducing inputs on the occupied part, one row per beam: along each beam
   they sit at equal quantiles of a weight mixing uniform density (the paper's "evenly
   distributed", share ``1 - adapt``) with the occupancy's variation (share ``adapt``), so
   range edges get more points than flat walls (measured: 14.1 -> 11.3 cm RMSD on the
   simulated tunnel at M=500). Each input is the centroid of its segment's cells.
3. *refine* -- hyper-parameters start from the sensor's geometry (:func:`initial_hyper`);
   optionally (``steps > 0``) Adam steps on Titsias' collapsed bound over a seeded subsample,
   stopping as soon as the bound stops improving. Off by default: on the simulated tunnel the
   bound kept rising while the reconstruction got worse, at ~1 s per step (docs/vsgp.md).
4. *fit* -- the closed-form optimal q(u) on a column-strided subset of the occupied cells; its
   mean at the inducing inputs is what the payload carries.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from lwbench import SensorModel

from .gp import Hyper, collapsed_bound, posterior_inducing_mean, rq_cross, rq_tensor

__all__ = [
    "FitConfig", "FitResult", "LS_FACTOR_AZ", "occupancy", "layout_inducing", "initial_hyper", "refine",
    "fit_scan",
]


# Azimuth lengthscale / mean inducing spacing along a beam (sweep in docs/vsgp.md).
LS_FACTOR_AZ = 1.5


@dataclass(frozen=True)
class FitConfig:
    num_inducing: int = 500
    adapt: float = 0.7
    jump_cap: float = 3.0
    noise_std: float = 0.05
    steps: int = 0
    lr: float = 0.1
    tol: float = 1e-3
    subsample: int = 2048
    fit_stride: int = 4
    learn_inducing: bool = False
    seed: int = 0


@dataclass
class FitResult:
    z: np.ndarray  # (M, 2) float64 azimuth, elevation (rad)
    u: np.ndarray  # (M,) float64 occupancy at z
    hyper: Hyper
    steps_run: int = 0
    bounds: list[float] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)


def occupancy(ranges: np.ndarray, r_oc: float) -> tuple[np.ndarray, np.ndarray]:
    """Mask of occupied cells ``0 < r < r_oc`` and the occupancy ``f = r_oc - r`` (0 elsewhere)."""
    occ = (ranges > 0) & (ranges < r_oc)
    return occ, np.where(occ, r_oc - ranges, 0.0)


def layout_inducing(occ: np.ndarray, f: np.ndarray, sensor: SensorModel, m: int, adapt: float,
                    jump_cap: float) -> np.ndarray:
    """One inducing row per beam; along each beam, points at equal quantiles of a weight that
    mixes uniform density (share ``1 - adapt``) with the occupancy's variation ``|df|`` (share
    ``adapt``, each step capped at ``jump_cap`` metres), so edges get more points than flat walls.
    Rows get points in proportion to their total weight (largest remainder)."""
    rows, cols = np.nonzero(occ)
    n_beams = occ.shape[0]
    if len(rows) == 0 or m == 0:
        return np.zeros((0, 2))
    az = sensor.azimuths_rad()[cols]
    el = sensor.elevations_rad[rows]
    if len(rows) <= m:
        return np.stack([az, el], axis=1)
    y = f[rows, cols]
    dy = np.abs(np.diff(y, prepend=y[0]))
    new_row = np.ones(len(rows), dtype=bool)
    new_row[1:] = rows[1:] != rows[:-1]
    dy[new_row] = 0.0
    dy = np.minimum(dy, jump_cap)
    total_dy = dy.sum()
    share = dy / total_dy if total_dy > 0 else np.full(len(rows), 1.0 / len(rows))
    w = (1 - adapt) / len(rows) + adapt * share
    row_w = np.bincount(rows, w, minlength=n_beams)
    row_n = np.bincount(rows, minlength=n_beams)
    quota = row_w / row_w.sum() * m
    alloc = np.minimum(np.floor(quota).astype(np.int64), row_n)
    rest = m - alloc.sum()
    if rest > 0:
        order = np.argsort(-(quota - alloc) + (alloc >= row_n) * 1e9, kind="stable")
        alloc[order[:rest]] += 1
    alloc = np.minimum(alloc, row_n)
    start = np.concatenate([[0], np.cumsum(row_w)[:-1]])
    cum = (np.cumsum(w) - w / 2 - start[rows]) / np.where(row_w[rows] > 0, row_w[rows], 1)
    seg = np.minimum((cum * alloc[rows]).astype(np.int64), np.maximum(alloc[rows] - 1, 0))
    offset = np.concatenate([[0], np.cumsum(alloc)[:-1]])
    key = offset[rows] + seg
    valid = alloc[rows] > 0
    counts = np.bincount(key[valid], minlength=int(alloc.sum()))
    nz = counts > 0
    cz = np.stack([np.bincount(key[valid], az[valid], minlength=len(counts))[nz] / counts[nz],
                   np.bincount(key[valid], el[valid], minlength=len(counts))[nz] / counts[nz]], axis=1)
    return cz


def initial_hyper(sensor: SensorModel, n_occupied: int, m: int, y: np.ndarray, noise_std: float) -> Hyper:
    """Hyper-parameters from the sensor's geometry, before any data-driven step.

    Elevation: one inducing row per beam, so the lengthscale is the beam spacing (adjacent beams
    often see different surfaces -- floor vs wall -- and must not be smoothed together).
    Azimuth: ``LS_FACTOR_AZ`` x the mean spacing of the inducing points along the occupied part
    of a beam (azimuth step x occupied cells per point); shorter lengthscales leave gaps that
    fall back to the zero mean, longer ones smooth edges away (factor chosen by the sweep in
    ``docs/vsgp.md``). The outputscale is the occupancy's second moment (zero-mean prior).
    """
    beams = sensor.elevations_rad
    beam_step = float(np.median(np.diff(beams))) if len(beams) > 1 else math.radians(2.0)
    ls_az = LS_FACTOR_AZ * sensor.azimuth_step_rad * max(1.0, n_occupied / max(1, m))
    scale = float(np.mean(np.square(y))) if len(y) else 1.0
    return Hyper(ls_az, beam_step, 1.0, max(scale, 1e-6), noise_std**2)


def _gpytorch_model(h: Hyper, device: torch.device):
    """GPyTorch RQ-ARD kernel (scaled) and Gaussian likelihood, initialised from ``h``."""
    import gpytorch

    kernel = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RQKernel(ard_num_dims=2)).to(device)
    lik = gpytorch.likelihoods.GaussianLikelihood(
        noise_constraint=gpytorch.constraints.GreaterThan(1e-6)
    ).to(device)
    kernel.base_kernel.lengthscale = torch.tensor([[h.ls_az, h.ls_el]], device=device)
    kernel.base_kernel.alpha = torch.tensor(h.alpha, device=device)
    kernel.outputscale = torch.tensor(h.outputscale, device=device)
    lik.noise = torch.tensor(h.noise, device=device)
    return kernel, lik


def _hyper_of(kernel, lik) -> Hyper:
    ls = kernel.base_kernel.lengthscale.detach().reshape(-1).double().cpu().numpy()
    return Hyper(float(ls[0]), float(ls[1]), float(kernel.base_kernel.alpha.detach()),
                 float(kernel.outputscale.detach()), float(lik.noise.detach()))


def refine(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, h: Hyper, cfg: FitConfig
           ) -> tuple[Hyper, torch.Tensor, list[float]]:
    """Adam on the collapsed bound; returns the best hyper-parameters (and inducing inputs) seen.

    Stops when a step improves the per-point bound by less than ``cfg.tol`` nats or makes it
    worse; the bound is evaluated on the same subsample every step, so the comparison is exact.
    """
    kernel, lik = _gpytorch_model(h, x.device)
    zp = torch.nn.Parameter(z.clone(), requires_grad=cfg.learn_inducing)
    params = list(kernel.parameters()) + list(lik.parameters()) + ([zp] if cfg.learn_inducing else [])
    opt = torch.optim.Adam(params, lr=cfg.lr)
    best = (-math.inf, h, z)
    bounds: list[float] = []
    for step in range(cfg.steps + 1):
        opt.zero_grad()
        ls, alpha, scale = kernel.base_kernel.lengthscale, kernel.base_kernel.alpha, kernel.outputscale
        zd = zp.double()
        kmm = rq_tensor(zd, zd, ls.double(), alpha.double(), scale.double())
        kmn = rq_tensor(zp, x, ls, alpha, scale)
        try:
            f = collapsed_bound(kmm, kmn, y, kernel.outputscale, lik.noise)
        except torch.linalg.LinAlgError:  # a step into an indefinite region: keep the best so far
            break
        val = float(f.detach())
        bounds.append(val)
        if not math.isfinite(val) or val < best[0] + (cfg.tol if step else -math.inf):
            if val > best[0]:
                best = (val, _hyper_of(kernel, lik), zp.detach().clone())
            break
        best = (val, _hyper_of(kernel, lik), zp.detach().clone())
        if step == cfg.steps:
            break
        (-f).backward()
        opt.step()
    return best[1], best[2], bounds


def fit_scan(ranges: np.ndarray, sensor: SensorModel, r_oc: float, cfg: FitConfig,
             device: torch.device, dtype: torch.dtype = torch.float32) -> FitResult:
    """Encode one range image into inducing inputs, their occupancy and hyper-parameters."""
    t0 = time.perf_counter()
    occ, f = occupancy(ranges, r_oc)
    z_np = layout_inducing(occ, f, sensor, cfg.num_inducing, cfg.adapt, cfg.jump_cap)
    rows, cols = np.nonzero(occ)
    y_all = f[rows, cols]
    h = initial_hyper(sensor, len(rows), max(1, len(z_np)), y_all, cfg.noise_std)
    t1 = time.perf_counter()
    timings = {"layout": t1 - t0}
    if len(z_np) == 0:
        return FitResult(z_np, np.zeros(0), h, timings=timings)
    az = sensor.azimuths_rad()
    el = sensor.elevations_rad

    def inputs(idx: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        x = np.stack([az[cols[idx]], el[rows[idx]]], axis=1)
        return (torch.as_tensor(x, dtype=dtype, device=device),
                torch.as_tensor(y_all[idx], dtype=dtype, device=device))

    z = torch.as_tensor(z_np, dtype=dtype, device=device)
    steps_run, bounds = 0, []
    if cfg.steps > 0 and len(rows) > len(z_np):
        rng = np.random.default_rng(cfg.seed)
        n_sub = min(cfg.subsample, len(rows))
        sub = np.sort(rng.choice(len(rows), size=n_sub, replace=False))
        xs, ys = inputs(sub)
        with torch.enable_grad():
            h, z, bounds = refine(xs, ys, z, h, cfg)
        steps_run = max(0, len(bounds) - 1)
    t2 = time.perf_counter()
    timings["refine"] = t2 - t1
    # Strided columns keep every beam and every occupied run; tiny scans use every cell.
    dense = len(rows) <= 4 * len(z_np)
    fit_idx = np.arange(len(rows)) if dense else np.flatnonzero(cols % max(1, cfg.fit_stride) == 0)
    xf, yf = inputs(fit_idx)
    with torch.no_grad():
        kmm = rq_cross(z.double(), z.double(), h)
        kmn = rq_cross(z, xf, h)
        u = posterior_inducing_mean(kmm, kmn, yf, h)
    timings["fit"] = time.perf_counter() - t2
    return FitResult(z.double().cpu().numpy(), u.cpu().numpy(), h, steps_run, bounds, timings)
