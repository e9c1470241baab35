"""The sparse-GP algebra VSGP needs: RQ-ARD kernel, collapsed Titsias bound, closed-form q(u),
and the base-side predictor.

Why not a GPyTorch ``ApproximateGP``: learning q(u) by gradient steps took ~100 s per scan here
(``MEASURED.md``). With a Gaussian likelihood the optimal q(u) of Titsias' bound has a closed
form, so only the five kernel/noise hyper-parameters are learned by gradient steps, and they
need only a few steps on a subsample because they start from the sensor's geometry.

Precision: the N x M kernel is evaluated in the working dtype (float32 by default), but every
M x M product and factorization is done in float64. The collapsed bound subtracts two terms of
size ~y'y/sigma^2, and float32 accumulation there is what made float32 SGPR diverge in
``MEASURED.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = [
    "Hyper", "rq_cross", "rq_tensor", "rq_grid", "chord", "cholesky", "collapsed_bound",
    "posterior_inducing_mean", "Predictor",
]

# Relative jitter on K_mm's diagonal: small enough not to bias the interpolation, large enough
# that float64 Cholesky never fails for inducing points closer than a lengthscale.
JITTER = 1e-6


@dataclass(frozen=True)
class Hyper:
    """RQ-ARD kernel ``s * (1 + d^2 / (2 alpha))^-alpha`` with ``d = |(x - x') / lengthscale|``,
    plus Gaussian noise variance. Lengthscales are (azimuth, elevation) in radians."""

    ls_az: float
    ls_el: float
    alpha: float
    outputscale: float
    noise: float

    def as_list(self) -> list[float]:
        return [self.ls_az, self.ls_el, self.alpha, self.outputscale, self.noise]

    def valid(self) -> bool:
        return all(math.isfinite(v) and v > 0 for v in self.as_list())


def chord(d: torch.Tensor) -> torch.Tensor:
    """Azimuth difference -> chord length ``2 sin(d / 2)`` on the unit circle.

    A scan is a full turn, so the columns on either side of the ``+-pi`` seam are neighbours:
    with plain differences the seam's cells had 14 cm error on a plain cylinder (no inducing
    point beyond it). Merely wrapping the difference into ``[-pi, pi)`` breaks positive
    definiteness once the lengthscale is a sizeable part of a turn (M=200 failed to factor).
    The chord is the Euclidean distance of the embedding ``(cos az, sin az)``, so the kernel is
    GPyTorch's RQ-ARD kernel on ``(cos az, sin az, el)`` -- positive definite for any
    lengthscale -- and equals the plain difference to O(d^3) for nearby cells."""
    return 2 * torch.sin(d / 2)


def _rq_from_sqdist(d2: torch.Tensor, alpha: float | torch.Tensor,
                    scale: float | torch.Tensor) -> torch.Tensor:
    """``scale * (1 + d2/(2 alpha))^-alpha``, computed in place on ``d2`` when no grad is needed."""
    if d2.requires_grad or isinstance(alpha, torch.Tensor) and alpha.requires_grad:
        return scale * torch.exp(-alpha * torch.log1p(d2 / (2 * alpha)))
    return d2.div_(2 * alpha).log1p_().mul_(-alpha).exp_().mul_(scale)


def rq_cross(x1: torch.Tensor, x2: torch.Tensor, h: Hyper) -> torch.Tensor:
    """Kernel matrix between ``x1 (N, 2)`` and ``x2 (M, 2)`` (columns azimuth, elevation)."""
    return rq_tensor(x1, x2, torch.tensor([h.ls_az, h.ls_el], dtype=x1.dtype, device=x1.device),
                     h.alpha, h.outputscale)


def rq_tensor(x1: torch.Tensor, x2: torch.Tensor, ls: torch.Tensor, alpha: float | torch.Tensor,
              scale: float | torch.Tensor) -> torch.Tensor:
    """Same kernel with tensor hyper-parameters (differentiable): GPyTorch's
    ``ScaleKernel(RQKernel(ard_num_dims=3))`` on ``(cos az, sin az, el)`` with lengthscales
    ``(ls_az, ls_az, ls_el)`` (see :func:`chord`), but from exact differences instead of GPyTorch's
    ``|a|^2 + |b|^2 - 2ab`` expansion, so that ``K_mm`` is accurate enough to factor in float64."""
    ls = ls.reshape(-1).to(x1.dtype)
    da = chord(x1[:, None, 0] - x2[None, :, 0]) / ls[0]
    de = (x1[:, None, 1] - x2[None, :, 1]) / ls[1]
    d2 = da.square() + de.square() if da.requires_grad else da.square_().add_(de.square_())
    if isinstance(alpha, torch.Tensor):
        alpha = alpha.to(x1.dtype)
    if isinstance(scale, torch.Tensor):
        scale = scale.to(x1.dtype)
    return _rq_from_sqdist(d2, alpha, scale)


def rq_grid(az: torch.Tensor, el: torch.Tensor, z: torch.Tensor, h: Hyper) -> torch.Tensor:
    """Kernel between the grid ``el x az`` (rows x columns) and ``z (M, 2)``: shape ``(R, C, M)``.

    The squared distance of a grid is separable, so only the transcendental part costs R*C*M.
    """
    da = (chord(az[:, None] - z[None, :, 0]) / h.ls_az).square_()  # (C, M)
    de = ((el[:, None] - z[None, :, 1]) / h.ls_el).square_()  # (R, M)
    d2 = de[:, None, :] + da[None, :, :]
    return _rq_from_sqdist(d2, h.alpha, h.outputscale)


def cholesky(a: torch.Tensor) -> torch.Tensor:
    """Cholesky factor, retrying with growing diagonal jitter (relative to the mean diagonal)
    when rounding makes ``a`` numerically indefinite; raises ``LinAlgError`` if that fails too."""
    factor, info = torch.linalg.cholesky_ex(a)
    scale = float(torch.diagonal(a).mean())
    eye = torch.eye(a.shape[0], dtype=a.dtype, device=a.device)
    for rel in (1e-6, 1e-4, 1e-2):
        if int(info) == 0:
            return factor
        factor, info = torch.linalg.cholesky_ex(a + rel * scale * eye)
    if int(info) != 0:
        raise torch.linalg.LinAlgError("matrix is not positive definite even with 1% jitter")
    return factor


def collapsed_bound(kmm: torch.Tensor, kmn: torch.Tensor, y: torch.Tensor, outputscale: torch.Tensor,
                    noise: torch.Tensor) -> torch.Tensor:
    """Titsias' collapsed lower bound (paper eq. 4), per training point, differentiable.

    ``F = log N(y | 0, s2 I + Q_nn) - tr(K_nn - Q_nn) / (2 s2)`` with ``Q_nn = K_nm K_mm^-1 K_mn``,
    evaluated through M x M matrices only (matrix determinant lemma and Woodbury), in float64.
    """
    kmm = kmm.double()
    kmn = kmn.double()
    y = y.double()
    noise = noise.double()
    n, m = kmn.shape[1], kmn.shape[0]
    eye = torch.eye(m, dtype=kmm.dtype, device=kmm.device)
    lm = torch.linalg.cholesky(kmm + JITTER * outputscale.double() * eye)
    a = torch.linalg.solve_triangular(lm, kmn, upper=False)  # L^-1 K_mn
    aat = a @ a.T
    lb = torch.linalg.cholesky(eye + aat / noise)
    c = torch.linalg.solve_triangular(lb, (a @ y)[:, None], upper=False)[:, 0] / noise
    logdet = n * torch.log(noise) + 2 * torch.log(torch.diagonal(lb)).sum()
    quad = (y @ y) / noise - c @ c
    trace = (n * outputscale.double() - torch.diagonal(aat).sum()) / noise
    return -0.5 * (n * math.log(2 * math.pi) + logdet + quad + trace) / n


def posterior_inducing_mean(kmm: torch.Tensor, kmn: torch.Tensor, y: torch.Tensor, h: Hyper) -> torch.Tensor:
    """Mean of the optimal q(u) at the inducing inputs: ``K_mm (s2 K_mm + K_mn K_nm)^-1 K_mn y``.

    Returns float64 ``(M,)``. The M x N product is taken in float64 (a float32 ``K_mn K_nm``
    loses the small eigenvalues that the solve needs).
    """
    kmm = kmm.double()
    kmn = kmn.double()
    m = kmm.shape[0]
    eye = torch.eye(m, dtype=kmm.dtype, device=kmm.device)
    sigma = h.noise * kmm + kmn @ kmn.T + JITTER * h.outputscale * h.noise * eye
    ls = cholesky(sigma)
    w = torch.cholesky_solve((kmn @ y.double())[:, None], ls)[:, 0]
    return kmm @ w


class Predictor:
    """Base-side GP: mean ``K_*m K_mm^-1 u`` and variance ``k_** - K_*m K_mm^-1 K_m*``.

    With ``u`` the posterior mean at the inducing inputs, the mean is exactly the encoder's
    sparse-GP posterior mean. The variance is the part of the prior the inducing points do not
    explain: low on the occupied surface where they sit, high in free space -- which is what the
    variance-based sampling thresholds.
    """

    def __init__(self, z: torch.Tensor, u: torch.Tensor, h: Hyper,
                 dtype: torch.dtype = torch.float32) -> None:
        self.z, self.h, self.dtype = z.to(dtype), h, dtype
        kmm = rq_cross(z.double(), z.double(), h)
        m = kmm.shape[0]
        kmm += JITTER * h.outputscale * torch.eye(m, dtype=kmm.dtype, device=kmm.device)
        lm = cholesky(kmm)
        self.weights = torch.cholesky_solve(u.double()[:, None], lm)[:, 0].to(dtype)
        self.chol = lm.to(dtype)

    def mean(self, k: torch.Tensor) -> torch.Tensor:
        """Posterior mean from a kernel block ``(..., M)``."""
        return k @ self.weights

    def variance(self, k: torch.Tensor) -> torch.Tensor:
        """Predictive variance (without noise) from a kernel block ``(..., M)``."""
        flat = k.reshape(-1, k.shape[-1])
        v = torch.linalg.solve_triangular(self.chol, flat.T, upper=False)
        var = self.h.outputscale - v.square().sum(0)
        return var.clamp_(min=0).reshape(k.shape[:-1])


def reference_seconds() -> float:
    """Median wall time of one 57,600 x 500 RQ kernel evaluation -- the decoder's dominant
    workload -- so that benchmarks report VSGP's times as ratios to a reference measured in the
    same process (the machines are shared and noisy)."""
    import time

    az = torch.linspace(-3.1, 3.1, 3600)
    el = torch.linspace(-0.26, 0.26, 16)
    z = torch.rand(500, 2, generator=torch.Generator().manual_seed(0))
    h = Hyper(0.1, 0.035, 1.0, 10.0, 0.01)
    times = []
    for _ in range(5):
        t = time.perf_counter()
        rq_grid(az, el, z, h)
        times.append(time.perf_counter() - t)
    return float(sorted(times)[len(times) // 2])
