"""What encoder and decoder must agree on about the values the GP models: the occupancy transform
of a range and its inverse, and the noise of an inducing value.

Its own module so that the decoder needs nothing of the encoder (they imported each other: the
encoder checks its payloads with the decoder's work budget, the decoder read these from the
encoder).
"""

from __future__ import annotations

import numpy as np

from .gp import Hyper

__all__ = ["LS_FACTOR_AZ", "occupancy", "to_range", "value_noise"]

# Azimuth lengthscale / mean inducing spacing along a beam (sweep in docs/vsgp.md).
LS_FACTOR_AZ = 1.5


def occupancy(r: np.ndarray, transform: str, r_oc: float) -> np.ndarray:
    """``f(r)``: ``r_oc - r`` (linear, the paper's) or ``1 / r`` (inverse)."""
    if transform == "linear":
        return r_oc - r
    return 1.0 / r


def to_range(f: np.ndarray, transform: str, r_oc: float) -> np.ndarray:
    """Inverse of :func:`occupancy`; ``inf`` where an inverse occupancy is not positive (free)."""
    if transform == "linear":
        return r_oc - f
    with np.errstate(divide="ignore"):
        return np.where(f > 0, 1.0 / np.where(f > 0, f, 1.0), np.inf)


def value_noise(h: Hyper, col_step: float) -> float:
    """Variance of an inducing value: the noise over the cells it averages, about
    ``ls_az / (LS_FACTOR_AZ * col_step)`` of them along its beam (the derived lengthscale is
    ``LS_FACTOR_AZ`` inducing spacings). Measured: 0.1x the noise variance cost the sim tunnel
    0.1 cm (8.34 -> 8.46, 90 cells a point) and took KITTI 00 frame 0 at 16,000 points from
    0.91 m to 0.67 m RMSD (7 cells a point); this rule gives 0.011x and 0.15x."""
    return h.noise * min(1.0, LS_FACTOR_AZ * col_step / h.ls_az)
