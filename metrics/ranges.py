"""Range metrics on directions, not cells: ``range_rmsd``, ``coverage``, ``false_returns``.

The VSGP paper's range RMSD (eq. 8) compares two clouds on the sensor's range image. Doing that
literally -- project both onto fixed cells, compare cell by cell -- measures the grid as much as
the codec: a real sensor does not fire through cell centres, so where a cell edge falls decides
whether an original return and its decoded copy land in the same cell (rotating a real scan and
its decoded cloud together by half a cell moved VSGP's coverage from 0.64 to 0.997 and Draco's
RMSD from 3.6 cm to 0.3 mm), and a codec that encodes to the same grid is scored on its own terms.

So the pairing is done on the returns' directions, relative to each other:

- each return gets angular coordinates in units of the sensor's spacing: azimuth in azimuth
  steps (periodic), elevation as a fractional beam index (piecewise linear in the beam table, so
  non-uniform tables such as the HDL-64E's get their local spacing);
- a decoded return ``q`` is a candidate partner of an original return ``p`` when it lies within
  ``tolerance`` spacings of it along both axes (default 0.5: half the beam and azimuth spacing,
  a window one cell in size centred on ``p`` itself);
- returns are paired **one-to-one, nearest first** (by 3-D distance among the candidates);
- ``range_rmsd`` = RMSD of ``|p| - |q|`` over the pairs; ``coverage`` = share of original
  returns with a partner; ``false_returns`` = share of decoded returns that are no original
  return's partner and have no original return within the tolerance.

Why one-to-one and nearest first, rather than "each original with its nearest decoded return
in direction": real scans hold several returns within one window (at short range each laser's
offset from the axis makes its returns' apparent elevation wander; at depth edges foreground
and background sit side by side). Pairing each original with the nearest *direction* then pairs
returns with other returns' copies: on KITTI 00 frame 0 it gave `random` (which keeps points
exactly) a 1.70 m RMSD and Draco at 14 bits (errors of millimetres) 20.6 cm. One-to-one,
nearest first, every kept or faithfully reproduced return pairs with its own copy.

Only relative directions and distances enter, so rotating both clouds about the sensor axis
changes nothing; a selection codec's kept points pair with themselves (``range_rmsd`` exactly 0,
``coverage`` = the share kept); a codec that drops half the returns covers half; a codec that
returns one point where the scan had two in one window covers one of them.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from lwbench import HIGHER, LOWER, Evaluation, FrameMetric, MetricId, Param, SensorModel
from lwbench.geometry import spherical

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

__all__ = ["RangeMetric", "direction_coordinates", "match_returns"]

# Room on either side of the beam table in the (non-periodic) elevation axis; the k-d tree's
# periodic topology needs a box, and returns this far outside the field of view are unpaired
# whatever the tolerance.
_BEAM_MARGIN = 16.0


def direction_coordinates(points: np.ndarray, sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """``(N, 2)`` coordinates (azimuth in steps in ``[0, n_azimuth)``, elevation as a beam index
    shifted into the tree's box) and the ranges; zero-range points get NaN coordinates."""
    r, az, el = spherical(points)
    col = np.mod((az + math.pi) / sensor.azimuth_step_rad, sensor.n_azimuth)
    col = np.where(col >= sensor.n_azimuth, 0.0, col)  # mod can round up to the period itself
    beams = sensor.elevations_rad
    if len(beams) == 1:
        # One beam (a 2-D laser): no beam spacing; elevation in azimuth steps keeps it isotropic.
        row = (el - beams[0]) / sensor.azimuth_step_rad
    else:
        idx = np.arange(len(beams), dtype=np.float64)
        row = np.interp(el, beams, idx)
        lo_gap, hi_gap = beams[1] - beams[0], beams[-1] - beams[-2]
        row = np.where(el < beams[0], (el - beams[0]) / lo_gap, row)
        row = np.where(el > beams[-1], len(beams) - 1 + (el - beams[-1]) / hi_gap, row)
    row = np.clip(row + _BEAM_MARGIN, 0.0, _box_rows(sensor) - 1e-9)
    coords = np.stack([col, row], axis=1)
    coords[r <= 0] = np.nan
    return coords, r


def _box_rows(sensor: SensorModel) -> float:
    return sensor.n_beams - 1 + 2 * _BEAM_MARGIN + 1.0


def _tree(coords: np.ndarray, sensor: SensorModel) -> cKDTree:
    from scipy.spatial import cKDTree  # here, not at import: `lwbench list` stays fast

    return cKDTree(coords, boxsize=[float(sensor.n_azimuth), _box_rows(sensor) + 4 * _BEAM_MARGIN])


def _greedy_matching(i: np.ndarray, j: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of candidate pairs ``(i[k], j[k])``, cheapest first.

    The same result as taking the pairs in order of ``cost`` (ties by ``i``, ``j``) and keeping
    each whose two ends are both still free, computed in rounds of "locally dominant" pairs --
    a pair that is the best remaining one of both its ends is in the greedy matching -- so the
    work is numpy array passes, not a Python loop over ~10^5 pairs. Real scans need a few rounds.
    """
    order = np.lexsort((j, i, cost))
    i, j = i[order], j[order]
    alive = np.ones(len(i), dtype=bool)
    mi, mj = [], []
    while alive.any():
        k = np.flatnonzero(alive)
        _, first_i = np.unique(i[k], return_index=True)
        _, first_j = np.unique(j[k], return_index=True)
        best_i = np.zeros(len(k), dtype=bool)
        best_i[first_i] = True
        best_j = np.zeros(len(k), dtype=bool)
        best_j[first_j] = True
        chosen = k[best_i & best_j]
        mi.append(i[chosen])
        mj.append(j[chosen])
        taken_i = np.zeros(int(i.max()) + 1, dtype=bool)
        taken_j = np.zeros(int(j.max()) + 1, dtype=bool)
        taken_i[i[chosen]] = True
        taken_j[j[chosen]] = True
        alive &= ~(taken_i[i] | taken_j[j])
    return np.concatenate(mi), np.concatenate(mj)


def match_returns(
    p_points: np.ndarray,
    q_points: np.ndarray,
    p_coords: np.ndarray,
    q_coords: np.ndarray,
    sensor: SensorModel,
    tolerance: float,
    p_tree: cKDTree | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pair original and decoded returns one-to-one within the direction window.

    Candidates are the decoded returns within ``tolerance`` spacings of an original return
    along both axes (a Chebyshev ball in the spacing-scaled coordinates); among them returns are
    matched nearest-first by 3-D distance, each original and each decoded return at most once.
    Returns, per original return, its partner's index in ``q`` (``-1``: none) and, per decoded
    return, whether any original return lies within its window.
    """
    p_idx = np.flatnonzero(np.isfinite(p_coords[:, 0]))
    q_idx = np.flatnonzero(np.isfinite(q_coords[:, 0]))
    partner = np.full(len(p_coords), -1, dtype=np.int64)
    near_p = np.zeros(len(q_coords), dtype=bool)
    if not len(p_idx) or not len(q_idx):
        return partner, near_p
    if p_tree is None:
        p_tree = _tree(p_coords[p_idx], sensor)
    q_tree = _tree(q_coords[q_idx], sensor)
    bound = float(np.nextafter(tolerance, np.inf))
    cand = p_tree.sparse_distance_matrix(q_tree, bound, p=np.inf, output_type="ndarray")
    if not len(cand):
        return partner, near_p
    a, b = cand["i"].astype(np.int64), cand["j"].astype(np.int64)
    near_p[q_idx[np.unique(b)]] = True
    gap = np.asarray(p_points, np.float64)[p_idx[a]] - np.asarray(q_points, np.float64)[q_idx[b]]
    ma, mb = _greedy_matching(a, b, np.einsum("ij,ij->i", gap, gap))
    partner[p_idx[ma]] = q_idx[mb]
    return partner, near_p


class RangeMetric(FrameMetric):
    name = "ranges"
    version = "2"  # 1 was the cell-based definition
    order = 20
    ids = (
        MetricId("range_rmsd", "m", LOWER, default=True),
        MetricId("coverage", "share", HIGHER, default=True),
        MetricId("false_returns", "share", LOWER, default=True),
    )
    description = (
        "original and decoded returns paired one-to-one, nearest first, within tolerance x the beam and "
        "azimuth spacing of each other: RMSD (m) of range differences over pairs; coverage = share of "
        "original returns with a partner; false_returns = share of decoded returns with no original nearby"
    )
    params = (
        Param("tolerance", "float", 0.5, "pairing window half-width, in beam / azimuth spacings", low=0.01, high=10.0),
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        sensor = ev.frame.sensor
        tol = self.config["tolerance"]
        p_coords, p_range = ev.cached("direction_coordinates", lambda: direction_coordinates(ev.frame.points, sensor))
        p_ok = np.isfinite(p_coords[:, 0])
        p_tree = ev.cached("direction_tree", lambda: _tree(p_coords[p_ok], sensor)) if p_ok.any() else None
        q_coords, q_range = direction_coordinates(ev.decoded, sensor)
        partner, near_p = match_returns(ev.frame.points, ev.decoded, p_coords, q_coords, sensor, tol, p_tree)
        n_p, n_q = int(p_ok.sum()), len(q_coords)
        paired = partner >= 0
        diff = p_range[paired] - q_range[partner[paired]]
        is_partner = np.zeros(n_q, dtype=bool)
        is_partner[partner[paired]] = True
        false = ~is_partner & ~near_p
        return {
            "range_rmsd": float(np.sqrt(np.mean(diff * diff))) if paired.any() else None,
            "coverage": float(paired.sum()) / n_p if n_p else None,
            "false_returns": float(false.sum()) / n_q if n_q else None,
        }
