"""The k-means start of the mixture's EM (:class:`~lwbench_plugins.gmm.mixture.TorchGaussianMixture`):
k-means++ centres, then a few Lloyd steps, in torch on the fit's device. Its own module so that
the mixture stays under 500 lines; the results are unchanged.
"""

from __future__ import annotations

import math

import torch

__all__ = ["assign", "kmeans_plusplus", "lloyd", "sq_dist"]


def sq_dist(X: torch.Tensor, C: torch.Tensor) -> torch.Tensor:
    """Squared distances ``(n, k)``; fine for argmin on centred data (not for likelihoods)."""
    return ((X * X).sum(1, keepdim=True) - 2 * X @ C.T + (C * C).sum(1)).clamp_min(0)


def kmeans_plusplus(X: torch.Tensor, k: int, gen: torch.Generator) -> torch.Tensor:
    """Greedy k-means++ centres (scikit-learn's variant: ``2 + log k`` candidates per step)."""
    n = len(X)
    trials = 2 + int(math.log(k))
    first = int(torch.randint(n, (1,), generator=gen, device=X.device))
    centers = X.new_empty(k, X.shape[1])
    centers[0] = X[first]
    cols = X.T.contiguous()  # (3, n): reductions over the coordinate axis stay contiguous
    d2 = ((cols - X[first].unsqueeze(1)) ** 2).sum(0)
    for i in range(1, k):  # sequential by definition; each step is vectorized over the points
        w = d2.double()
        w = w if float(w.sum()) > 0 else torch.ones_like(w)  # all points coincide with centres
        cand = torch.multinomial(w, trials, replacement=True, generator=gen)
        diff = cols.unsqueeze(1) - X[cand].T.unsqueeze(2)  # (3, trials, n)
        dc = torch.minimum(d2.unsqueeze(0), (diff * diff).sum(0))
        best = int(torch.argmin(dc.sum(1)))
        centers[i] = X[cand[best]]
        d2 = dc[best]
    return centers


def assign(X: torch.Tensor, C: torch.Tensor, chunk: int) -> torch.Tensor:
    return torch.cat([sq_dist(X[s : s + chunk], C).argmin(1) for s in range(0, len(X), chunk)])


def lloyd(X: torch.Tensor, C: torch.Tensor, iters: int, chunk: int) -> torch.Tensor:
    """A few Lloyd steps; a centre that loses all its points stays where it was."""
    k = len(C)
    for _ in range(iters):
        lab = assign(X, C, chunk)
        cnt = torch.bincount(lab, minlength=k).to(X.dtype)
        sums = torch.zeros_like(C).index_add_(0, lab, X)
        newc = torch.where(cnt.unsqueeze(1) > 0, sums / cnt.clamp_min(1).unsqueeze(1), C)
        if torch.equal(newc, C):
            break
        C = newc
    return C
