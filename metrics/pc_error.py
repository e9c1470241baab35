"""D1 and D2 (point-to-point and point-to-plane) errors exactly as MPEG's pc_error computes them,
so that a PSNR lwbench prints can be set beside a published one.

What pc_error does and this module follows (its defaults: ``dropdups=2``, ``averageNormals=1``):

- **Duplicate points** of each cloud are merged first (points with identical coordinates count
  once).
- **The decoded cloud's normals come from the original's**, not from the decoded points: every
  original point adds its normal to its nearest decoded point (to each of them, when several are
  at exactly the same distance), and each decoded point takes the *average* of what it received
  -- not renormalised, so normals that disagree shorten; a decoded point that no original chose
  takes the average normal of its nearest original point(s).
- **Original -> decoded** errors are projected on the *decoded* point's normal (averaged over
  decoded points tied at the nearest distance, within 1e-8 in squared distance);
  **decoded -> original** errors on the original's normal (likewise averaged over ties).
- The point-to-point error is the squared distance to the nearest point.

lwbench's D2 before version 2 of the geometry metric projected both directions on the original
point's own normal, which agrees for codecs that keep every point and reads 3 dB too low for
those that drop points (random, voxel: issue 36).
"""

from __future__ import annotations

import numpy as np

__all__ = ["PcErrors", "pc_errors", "transfer_normals", "unique_points"]

#: pc_error's bound on the neighbours searched for ties (it grows the search 5 at a time to 30).
MAX_TIES = 30
#: pc_error's tolerance for "the same distance" when it averages the error over tied neighbours.
TIE_TOLERANCE = 1e-8


def unique_points(points: np.ndarray) -> np.ndarray:
    """The cloud with duplicate points merged (pc_error's ``dropdups``), in a stable order."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) == 0:
        return pts.reshape(0, 3)
    _, first = np.unique(pts, axis=0, return_index=True)
    return pts[np.sort(first)]


def _nearest_sets(tree, data: np.ndarray, queries: np.ndarray, exact: bool) -> tuple[np.ndarray, np.ndarray,
                                                                                      dict[int, np.ndarray]]:
    """Nearest neighbour of each query in ``data`` (index, squared distance) and, for the few
    queries whose nearest distance is shared by several points, all of them (``exact``: equal
    squared distances, as pc_error's normal transfer; else consecutive ones within
    :data:`TIE_TOLERANCE`, as its error loop)."""
    k = min(2, len(data))
    _, idx = tree.query(queries, k=k)
    idx = idx.reshape(len(queries), k)
    sq = np.sum((queries[:, None, :] - data[idx]) ** 2, axis=2)
    ties: dict[int, np.ndarray] = {}
    if k == 2:
        tied = sq[:, 1] == sq[:, 0] if exact else np.abs(sq[:, 1] - sq[:, 0]) < TIE_TOLERANCE
        kk = min(MAX_TIES, len(data))
        for row in np.flatnonzero(tied):
            _, many = tree.query(queries[row], k=kk)
            many = np.atleast_1d(many)
            d2 = np.sum((queries[row] - data[many]) ** 2, axis=1)
            order = np.argsort(d2, kind="stable")
            many, d2 = many[order], d2[order]
            if exact:
                keep = d2 == d2[0]
            else:
                keep = np.concatenate([[True], np.cumprod(np.abs(np.diff(d2)) < TIE_TOLERANCE).astype(bool)])
            ties[int(row)] = many[keep]
            idx[row, 0], sq[row, 0] = many[0], d2[0]
    return idx[:, 0], sq[:, 0], ties


def transfer_normals(original: np.ndarray, normals: np.ndarray, decoded: np.ndarray, tree_original=None,
                     tree_decoded=None) -> np.ndarray:
    """The decoded cloud's normals as pc_error derives them from the original's (module notes)."""
    from scipy.spatial import cKDTree

    tree_decoded = tree_decoded or cKDTree(decoded)
    tree_original = tree_original or cKDTree(original)
    j, _, ties = _nearest_sets(tree_decoded, decoded, original, exact=True)
    summed = np.zeros_like(decoded, dtype=np.float64)
    counts = np.zeros(len(decoded), dtype=np.int64)
    single = np.ones(len(original), dtype=bool)
    single[list(ties)] = False
    np.add.at(summed, j[single], normals[single])
    np.add.at(counts, j[single], 1)
    for i, many in ties.items():
        summed[many] += normals[i]
        counts[many] += 1
    out = np.zeros_like(summed)
    chosen = counts > 0
    out[chosen] = summed[chosen] / counts[chosen, None]
    orphans = np.flatnonzero(~chosen)
    if len(orphans):
        i, _, oties = _nearest_sets(tree_original, original, decoded[orphans], exact=True)
        out[orphans] = normals[i]
        for row, many in oties.items():
            out[orphans[row]] = normals[many].mean(axis=0)
    return out


def _plane_errors(queries: np.ndarray, data: np.ndarray, data_normals: np.ndarray, nearest: np.ndarray,
                  sq: np.ndarray, ties: dict[int, np.ndarray]) -> np.ndarray:
    """Per query: its error vector projected on the nearest point's normal, squared (averaged over
    tied nearest points; a missing normal falls back to the point-to-point error)."""
    err = np.einsum("ij,ij->i", queries - data[nearest], data_normals[nearest]) ** 2
    bad = ~np.isfinite(data_normals[nearest]).all(axis=1)
    err[bad] = sq[bad]
    for row, many in ties.items():
        proj = np.einsum("ij,ij->i", queries[row] - data[many], data_normals[many]) ** 2
        err[row] = proj.mean()
    return err


class PcErrors:
    """Mean squared point-to-point and point-to-plane errors in both directions."""

    def __init__(self, d1_ab: float, d1_ba: float, d2_ab: float, d2_ba: float) -> None:
        self.d1_ab, self.d1_ba, self.d2_ab, self.d2_ba = d1_ab, d1_ba, d2_ab, d2_ba


def pc_errors(original: np.ndarray, normals: np.ndarray, decoded: np.ndarray, tree_original=None) -> PcErrors:
    """D1 and D2 MSEs of ``decoded`` against ``original`` as pc_error computes them; ``normals``
    are the original's (one per point of ``original``, which has no duplicate points: see
    :func:`unique_points`); ``decoded`` is merged here."""
    from scipy.spatial import cKDTree

    q = unique_points(decoded)
    tree_original = tree_original or cKDTree(original)
    tree_decoded = cKDTree(q)
    normals_q = transfer_normals(original, normals, q, tree_original, tree_decoded)
    j, sq_ab, ties_ab = _nearest_sets(tree_decoded, q, original, exact=False)
    i, sq_ba, ties_ba = _nearest_sets(tree_original, original, q, exact=False)
    d2_ab = _plane_errors(original, q, normals_q, j, sq_ab, ties_ab)
    d2_ba = _plane_errors(q, original, normals, i, sq_ba, ties_ba)
    return PcErrors(float(sq_ab.mean()), float(sq_ba.mean()), float(d2_ab.mean()), float(d2_ba.mean()))
