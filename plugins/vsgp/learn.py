"""Hyper-parameter learning: Adam steps on Titsias' collapsed bound, per tile (``steps > 0``).

Off by default: on the simulated tunnel the bound kept rising while the reconstruction got
worse, at ~1 s per step with one GP over the scan (docs/vsgp.md). ``mode=paper`` turns it on,
and a stream's warm start (``warm_start``) begins each frame's steps at the previous frame's
values, so they stop sooner.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .gp import Hyper, collapsed_bound, rq_tensor

__all__ = ["refine"]


def _gpytorch_model(h: Hyper, device: torch.device):
    """GPyTorch RQ-ARD kernel (scaled) and Gaussian likelihood, initialised from ``h``."""
    import gpytorch

    kernel = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RQKernel(ard_num_dims=2)).to(device).double()
    lik = (
        gpytorch.likelihoods.GaussianLikelihood(noise_constraint=gpytorch.constraints.GreaterThan(1e-12))
        .to(device)
        .double()
    )
    kernel.base_kernel.lengthscale = torch.tensor([[h.ls_az, h.ls_el]], device=device, dtype=torch.float64)
    kernel.base_kernel.alpha = torch.tensor(h.alpha, device=device, dtype=torch.float64)
    kernel.outputscale = torch.tensor(h.outputscale, device=device, dtype=torch.float64)
    lik.noise = torch.tensor(max(h.noise, 2e-12), device=device, dtype=torch.float64)
    return kernel, lik


def _hyper_of(kernel, lik) -> Hyper:
    ls = kernel.base_kernel.lengthscale.detach().reshape(-1).double().cpu().numpy()
    vals = [
        float(ls[0]),
        float(ls[1]),
        float(kernel.base_kernel.alpha.detach()),
        float(kernel.outputscale.detach()),
        float(lik.noise.detach()),
    ]
    return Hyper(*(float(np.float32(v)) for v in vals))


def refine(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor, h: Hyper, cfg) -> tuple[Hyper, torch.Tensor, list[float]]:
    """Adam on the collapsed bound; returns the best hyper-parameters (and inducing inputs) seen.

    Stops when a step improves the per-point bound by less than ``cfg.tol`` nats or makes it
    worse; the bound is evaluated on the same subsample every step, so the comparison is exact.
    With ``learn_inducing`` the inducing points move along their beams (azimuth only: the
    payload places each on a beam).
    """
    kernel, lik = _gpytorch_model(h, x.device)
    z_az = torch.nn.Parameter(z[:, 0].clone(), requires_grad=cfg.learn_inducing)
    params = list(kernel.parameters()) + list(lik.parameters()) + ([z_az] if cfg.learn_inducing else [])
    opt = torch.optim.Adam(params, lr=cfg.lr)
    best = (-math.inf, h, z)
    bounds: list[float] = []
    for step in range(cfg.steps + 1):
        opt.zero_grad()
        ls, alpha, scale = kernel.base_kernel.lengthscale, kernel.base_kernel.alpha, kernel.outputscale
        zp = torch.stack([z_az, z[:, 1]], dim=1)
        kmm = rq_tensor(zp, zp, ls, alpha, scale)
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
