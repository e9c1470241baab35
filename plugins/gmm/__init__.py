"""``gmm``: Gaussian-mixture codec (the VSGP paper's GMM baseline) and its torch estimator."""

from __future__ import annotations

from lwbench import hookimpl

from .codec import GMMCodec, body_size
from .mixture import ConvergenceWarning, NotFittedError, TorchGaussianMixture

__all__ = ["GMMCodec", "TorchGaussianMixture", "ConvergenceWarning", "NotFittedError", "body_size"]


@hookimpl
def lwbench_codecs() -> list[type[GMMCodec]]:
    return [GMMCodec]
