"""``gmm``: Gaussian-mixture codec (the VSGP paper's GMM baseline) and its torch estimator."""

from __future__ import annotations

from lwbench import hookimpl

from .codec import GMMCodec, body_size

__all__ = ["GMMCodec", "TorchGaussianMixture", "ConvergenceWarning", "NotFittedError", "body_size"]


def __getattr__(name: str):
    # The estimator needs torch; import it only when asked (plugin discovery stays fast).
    if name in ("TorchGaussianMixture", "ConvergenceWarning", "NotFittedError"):
        from . import mixture

        return getattr(mixture, name)
    raise AttributeError(name)


@hookimpl
def lwbench_codecs() -> list[type[GMMCodec]]:
    return [GMMCodec]
