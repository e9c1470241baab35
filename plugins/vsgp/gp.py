"""The sparse-GP algebra VSGP needs: RQ-ARD kernel, collapsed Titsias bound, closed-form q(u),
and the base-side predictor.

Why not a GPyTorch ``ApproximateGP``: learning q(u) by gradient steps took ~100 s per scan here
(``MEASURED.md``). With a Gaussian likelihood the optimal q(u) of Titsias' bound has a closed
form, so only the five kernel/noise hyper-parameters are learned by gradient steps (optional).

**Separable distances.** Cells lie on a grid (beam rows x azimuth columns) and inducing points
on beam rows, so the squared scaled distance ``d2 = de2[row, j] + da2[col, j]`` is a sum of two
small tables (``rows x M`` and ``cols x M``); only the RQ transform costs one operation per
``(cell, inducing point)`` entry -- a reciprocal for ``alpha = 1`` (the sensor-derived default),
``exp(-alpha log1p(.))`` otherwise. Measured on the sim tunnel: the same maths as the direct
kernel to 4e-5 m, 0.84x its time (issue 19's prototype).

**Precision.** Everything is float64: the ``K_mn K_nm`` product taken in float32 put up to 0.55 m
of error in the inducing values (``MEASURED.md``), and the collapsed bound subtracts two terms of
size ``y'y / sigma^2``. The local GPs (``grid.py``) keep each tile's ``M`` small enough that
float64 costs little.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = [
    "Hyper",
    "rq_cross",
    "rq_tensor",
    "rq_grid",
    "chord",
    "chord_sq",
    "cholesky",
    "collapsed_bound",
    "posterior_inducing_mean",
    "Predictor",
    "KernelTables",
    "rq_from_sqdist",
    "reference_seconds",
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


def chord_sq(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``chord(a_i - b_j)^2`` for every pair, ``(N, M)``, as one rank-2 product: with
    ``2 sin((a - b) / 2) = 2 (sin(a/2) cos(b/2) - cos(a/2) sin(b/2))`` only ``N + M`` sines and
    cosines are evaluated instead of ``N * M`` (the half angles keep small chords accurate:
    absolute error ~1e-16)."""
    pa = torch.stack([torch.sin(a / 2), -torch.cos(a / 2)], dim=1)
    pb = torch.stack([torch.cos(b / 2), torch.sin(b / 2)], dim=0)
    return (pa @ pb).mul_(2.0).square_()


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


def rq_from_sqdist(d2: torch.Tensor, alpha: float | torch.Tensor, scale: float | torch.Tensor) -> torch.Tensor:
    """``scale * (1 + d2/(2 alpha))^-alpha``, in place on ``d2`` when no gradient is needed.

    ``alpha = 1`` (the sensor-derived default) is a reciprocal instead of a log and an exp: the
    transcendental part was 32 % of an encode (``MEASURED.md``)."""
    if d2.requires_grad or isinstance(alpha, torch.Tensor) and alpha.requires_grad:
        return scale * torch.exp(-alpha * torch.log1p(d2 / (2 * alpha)))
    if float(alpha) == 1.0:
        return d2.mul_(0.5).add_(1.0).reciprocal_().mul_(scale)
    return d2.div_(2 * alpha).log1p_().mul_(-alpha).exp_().mul_(scale)


def rq_cross(x1: torch.Tensor, x2: torch.Tensor, h: Hyper) -> torch.Tensor:
    """Kernel matrix between ``x1 (N, 2)`` and ``x2 (M, 2)`` (columns azimuth, elevation)."""
    return rq_tensor(x1, x2, torch.tensor([h.ls_az, h.ls_el], dtype=x1.dtype, device=x1.device), h.alpha, h.outputscale)


def rq_tensor(
    x1: torch.Tensor, x2: torch.Tensor, ls: torch.Tensor, alpha: float | torch.Tensor, scale: float | torch.Tensor
) -> torch.Tensor:
    """Same kernel with tensor hyper-parameters (differentiable): GPyTorch's
    ``ScaleKernel(RQKernel(ard_num_dims=3))`` on ``(cos az, sin az, el)`` with lengthscales
    ``(ls_az, ls_az, ls_el)`` (see :func:`chord`), but from the chord's half-angle form instead of
    GPyTorch's ``|a|^2 + |b|^2 - 2ab`` expansion, so that ``K_mm`` is accurate enough to factor."""
    ls = ls.reshape(-1).to(x1.dtype)
    de = (x1[:, None, 1] - x2[None, :, 1]) / ls[1]
    da2 = chord_sq(x1[:, 0], x2[:, 0]) / ls[0].square()
    d2 = da2 + de.square() if da2.requires_grad else da2.add_(de.square_())
    if isinstance(alpha, torch.Tensor):
        alpha = alpha.to(x1.dtype)
    if isinstance(scale, torch.Tensor):
        scale = scale.to(x1.dtype)
    return rq_from_sqdist(d2, alpha, scale)


class KernelTables:
    """The separable parts of the kernel between grid cells and inducing points ``z (M, 2)``:
    ``da2 (C, M)`` over column azimuths and ``de2 (R, M)`` over row elevations (float64)."""

    def __init__(self, col_az: torch.Tensor, row_el: torch.Tensor, z: torch.Tensor, h: Hyper) -> None:
        self.h = h
        self.da2 = chord_sq(col_az, z[:, 0]).div_(h.ls_az**2)
        self.de2 = ((row_el[:, None] - z[None, :, 1]) / h.ls_el).square_()

    def cells(self, rows: torch.Tensor, cols: torch.Tensor) -> torch.Tensor:
        """``K_nm (N, M)`` for cells ``(rows[i], cols[i])`` (indices into the tables)."""
        return rq_from_sqdist(self.de2[rows] + self.da2[cols], self.h.alpha, self.h.outputscale)

    def grid(self, r0: int = 0, r1: int | None = None) -> torch.Tensor:
        """``(rows, cols, M)`` for every cell of rows ``r0:r1`` x every column."""
        d2 = self.de2[r0:r1, None, :] + self.da2[None, :, :]
        return rq_from_sqdist(d2, self.h.alpha, self.h.outputscale)


def rq_grid(az: torch.Tensor, el: torch.Tensor, z: torch.Tensor, h: Hyper) -> torch.Tensor:
    """Kernel between the grid ``el x az`` (rows x columns) and ``z (M, 2)``: shape ``(R, C, M)``."""
    return KernelTables(az, el, z, h).grid()


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


def collapsed_bound(
    kmm: torch.Tensor, kmn: torch.Tensor, y: torch.Tensor, outputscale: torch.Tensor, noise: torch.Tensor
) -> torch.Tensor:
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


def posterior_inducing_mean(
    kmm: torch.Tensor, knm: torch.Tensor, y: torch.Tensor, h: Hyper, sqrt_weights: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean of the optimal q(u) at the inducing inputs: ``K_mm (s2 K_mm + K_mn W K_nm)^-1 K_mn W y``.

    ``knm`` is ``(N, M)``; ``W`` (``sqrt_weights`` squared, default 1) counts how many cells each
    row of ``knm`` stands for (binned data). Everything is taken in float64 (a float32
    ``K_mn K_nm`` loses the small eigenvalues the solve needs). Returns ``(M,)`` float64."""
    kmm = kmm.double()
    knm = knm.double()
    y = y.double()
    if sqrt_weights is not None:
        knm = knm * sqrt_weights.double()[:, None]
        y = y * sqrt_weights.double()
    m = kmm.shape[0]
    eye = torch.eye(m, dtype=kmm.dtype, device=kmm.device)
    sigma = h.noise * kmm + knm.T @ knm + JITTER * h.outputscale * h.noise * eye
    ls = cholesky(sigma)
    w = torch.cholesky_solve((knm.T @ y.double())[:, None], ls)[:, 0]
    return kmm @ w


class Predictor:
    """Base-side GP, "trained on the inducing points" (paper §IV-B): mean
    ``K_*m (K_mm + l I)^-1 u`` and variance ``k_** - K_*m (K_mm + l I)^-1 K_m*``.

    ``u`` is the encoder's posterior mean at the inducing inputs and ``l`` (``u_noise``) its
    uncertainty: each value is the average of the cells around its point, so about the noise
    variance over the cells per point. Interpolating ``u`` exactly (``l`` = 0) reproduces the
    encoder's sparse-GP mean, but where points crowd at depth edges ``K_mm`` is near-singular
    and the interpolant rings: a tile of KITTI 00 frame 0 put a 24.5 m wall at 72 m. The
    variance is the part of the prior the inducing points do not explain: low on the occupied
    surface where they sit, high in free space -- which is what the variance-based sampling
    thresholds.
    """

    def __init__(
        self, z: torch.Tensor, u: torch.Tensor, h: Hyper, u_noise: float = 0.0, dtype: torch.dtype = torch.float64
    ) -> None:
        self.z, self.h, self.dtype = z.to(dtype), h, dtype
        if len(u) == 0:  # a tile with no return: the prior everywhere
            self.weights = torch.zeros(0, dtype=dtype, device=z.device)
            self.chol = torch.zeros((0, 0), dtype=dtype, device=z.device)
            return
        kmm = rq_cross(z.double(), z.double(), h)
        m = kmm.shape[0]
        kmm += max(u_noise, JITTER * h.outputscale) * torch.eye(m, dtype=kmm.dtype, device=kmm.device)
        lm = cholesky(kmm)
        self.weights = torch.cholesky_solve(u.double()[:, None], lm)[:, 0].to(dtype)
        self.chol = lm.to(dtype)

    def mean(self, k: torch.Tensor) -> torch.Tensor:
        """Posterior mean from a kernel block ``(..., M)``."""
        return k @ self.weights

    def variance(self, k: torch.Tensor) -> torch.Tensor:
        """Predictive variance (without noise) from a kernel block ``(..., M)``."""
        if k.shape[-1] == 0:
            return torch.full(k.shape[:-1], self.h.outputscale, dtype=k.dtype, device=k.device)
        flat = k.reshape(-1, k.shape[-1])
        v = torch.linalg.solve_triangular(self.chol, flat.T, upper=False)
        var = self.h.outputscale - v.square().sum(0)
        return var.clamp_(min=0).reshape(k.shape[:-1])


def reference_seconds(repeats: int = 5) -> float:
    """Median wall time of one 57,600 x 500 float64 RQ kernel (alpha = 1) computed as
    ``|x|^2 + |z|^2 - 2 X Z^T`` in numpy -- issue 19's reference: VSGP's encode and decode are
    reported as ratios to it, measured in the same process, because the machines are shared."""
    import time

    import numpy as np

    rng = np.random.default_rng(0)
    x, z = rng.uniform(size=(57_600, 3)), rng.uniform(size=(500, 3))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        d2 = (x * x).sum(1)[:, None] + (z * z).sum(1)[None, :] - 2.0 * (x @ z.T)
        k = 10.0 * (1.0 + d2 / 2.0) ** -1.0
        times.append(time.perf_counter() - t)
        del k
    return float(sorted(times)[len(times) // 2])
