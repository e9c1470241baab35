"""Harris-3D as PCL's ``HarrisKeypoint3D`` defines it, vectorized.

PCL (``keypoints/impl/harris_3d.hpp``): estimate a normal at every point from its neighbours
within ``radius``; average the outer products ``n n^T`` of the valid normals within the same
radius (``calculateNormalCovar``); turn that 3x3 matrix ``C`` into a response; keep the points
whose response is ``>= threshold`` and no smaller than any neighbour's within ``radius``.

Responses (PCL's ``ResponseMethod``; all cheap once ``C`` exists, so all are offered):
- ``harris``: ``k + det(C) - k trace(C)^2`` with ``k = 0.04`` -- PCL adds the constant ``k``
  so that a point with no valid normals (response 0) and a flat patch (``det = 0``,
  ``trace = 1``) both score 0 and a 3-plane corner (``C = I/3``) scores ``1/27 > 0``;
- ``noble``: ``det / trace``; ``lowe``: ``det / trace^2``; ``tomasi``: smallest eigenvalue of
  ``C``; ``curvature``: the normal estimation's surface variation
  ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` of the point scatter.
PCL's optional sub-point corner refinement is left out: a selector must return scan points.
"""

from __future__ import annotations

import numpy as np

from lwbench import Param

from ._base import MAX_NN_PARAM, KeypointSelector, voxel_param
from ._geometry import (
    Neighbourhood,
    det_sym6,
    eigvals_sym6,
    eigvec_sym6,
    first_beaten,
    gathered_moments,
    hybrid_neighbourhood,
    nms_levels,
    radius_nms,
    scatter,
    trace_sym6,
)

__all__ = ["Harris3D", "harris_response"]

METHODS = ("harris", "noble", "lowe", "tomasi", "curvature")


def harris_response(
    points: np.ndarray, radius: float, max_nn: int, method: str = "harris", k: float = 0.04
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCL's Harris-3D response per point, its keypoints, and what the budget rule needs.

    Returns ``(response, keypoint, defined, beaten_at)``, all ``(N,)``: ``defined`` is False
    where no valid normal lies in the neighbourhood (PCL leaves the response at 0 there);
    ``keypoint`` = local maxima on the capped neighbourhood, re-suppressed among themselves
    over the full radius (:func:`radius_nms`); ``beaten_at`` = :func:`first_beaten`.
    """
    nb = hybrid_neighbourhood(points, max_nn, radius)
    count, _, s = scatter(points, nb)
    lam = eigvals_sym6(s)
    normal, ok = eigvec_sym6(s, lam[0])
    ok &= count >= 3  # PCL's NormalEstimation gives NaN with fewer than 3 neighbours
    if method == "curvature":  # PCL: the normal estimation's surface variation
        tot = lam.sum(axis=0)
        defined = ok & (tot > 0)
        resp = np.where(defined, lam[0] / np.where(defined, tot, 1.0), 0.0)
    else:
        resp, defined = _normal_covariance_response(nb, normal, ok, method, k)
    beaten_at = first_beaten(resp, nb)
    keypoint = radius_nms(points, resp, (beaten_at == nb.idx.shape[1]) & defined, radius)
    return resp, keypoint, defined, beaten_at


def _normal_covariance_response(
    nb: Neighbourhood, normal: np.ndarray, ok: np.ndarray, method: str, k: float
) -> tuple[np.ndarray, np.ndarray]:
    """PCL's responses from the mean ``n n^T`` of the valid normals around each point."""
    # Mean of n n^T over the neighbours whose normal is valid (calculateNormalCovar): invalid
    # slots read an appended zero column and invalid normals are zeroed, so they add nothing.
    n = len(normal[0])
    nrm = np.zeros((3, n + 1), dtype=np.float32)
    nrm[:, :n] = np.where(ok, normal, 0.0)
    _, c = gathered_moments(nrm, nb.idx, valid=nb.valid)
    # Every valid normal is a unit vector and adds exactly 1 (to float32 rounding) to the
    # trace of sum n n^T, an invalid one 0: the trace rounds to their count, without the
    # (N, K) gather of the validity flags.
    cnt = np.rint(trace_sym6(c))
    c /= np.maximum(cnt, 1.0)
    trace = trace_sym6(c)
    det = det_sym6(c)
    defined = trace != 0
    safe_tr = np.where(defined, trace, 1.0)
    if method == "harris":
        r = k + det - k * trace * trace
    elif method == "noble":
        r = det / safe_tr
    elif method == "lowe":
        r = det / (safe_tr * safe_tr)
    elif method == "tomasi":
        r = eigvals_sym6(c)[0]
    else:
        raise ValueError(f"harris3d: unknown method {method!r}; choose from {METHODS}")
    return np.where(defined, r, 0.0), defined


class Harris3D(KeypointSelector):
    """Corners of the normal field (PCL ``HarrisKeypoint3D``), budgeted.

    Budget rule: tier 0 = PCL's keypoints (local maxima over the radius with response
    ``>= threshold``), ranked by response; then, when they are fewer than the budget, points
    above the threshold that are local maxima over ever smaller neighbourhoods
    (:func:`~._geometry.nms_levels`), then the other points above it, then every other point
    with a response, each tier ranked by response; last, points without a valid normal.
    Exactly ``budget`` points come back.

    ``threshold`` 1e-6 (PCL's default is 0): a flat patch's response is 0 up to rounding
    (~1e-7 in float32, PCL's precision too), and with 0 about half of a KITTI frame's NMS
    maxima (1,075 of 2,201) were such flat-ground noise, ranked ahead of real corners that
    merely had a stronger neighbour.

    Default radius 0.5 m (PCL leaves it to the user): ~2 HDL-64E ring spacings at 30 m and one
    VLP-16 ring spacing at ~15 m, so neighbourhoods span more than one ring and normals are
    defined on both sensors. ``max_nn=16`` caps the dense near field (a KITTI frame has a
    median of 64+ points within 0.5 m); ``voxel=0.1`` thins it first (see ``voxel_param``).
    """

    name = "harris3d"
    in_default_run = True
    description = "Harris-3D keypoints (PCL HarrisKeypoint3D: normal covariance + NMS), budgeted"
    params = (
        *KeypointSelector.params,
        Param("radius", "float", 0.5, "normal / covariance / NMS radius in metres", low=1e-3, high=100.0),
        MAX_NN_PARAM,
        voxel_param(0.1),
        Param("method", "str", "harris", "response (PCL ResponseMethod)", choices=METHODS),
        Param("k", "float", 0.04, "Harris constant (PCL hard-codes 0.04)", low=0.0, high=0.25),
        Param("threshold", "float", 1e-6, "PCL response threshold for keypoints (and top-up maxima)"),
    )

    def rank(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cfg = self.config
        resp, is_max, defined, beaten_at = harris_response(
            points, cfg["radius"], cfg["max_nn"], cfg["method"], cfg["k"]
        )
        strong = defined & (resp >= cfg["threshold"])
        tier = nms_levels(beaten_at, min(cfg["max_nn"], len(points)), strong)
        tier[~defined] = tier.max() + 1
        tier[is_max & strong] = 0
        return tier, resp
