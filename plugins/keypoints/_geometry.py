"""Vectorized neighbourhood geometry shared by the keypoint detectors.

Every detector here needs the same few things for *every* point of a 100k-point scan:
its neighbours within a radius, a 3x3 scatter matrix over them, and that matrix's eigen
decomposition. Doing these per point in Python would take minutes, so:

- neighbourhoods are *hybrid* (Open3D's ``KDTreeSearchParamHybrid``): the ``max_nn`` nearest
  points that lie within ``radius``, from one ``cKDTree.query(k=max_nn,
  distance_upper_bound=radius, workers=-1)`` call -- a dense ``(N, max_nn)`` index array with
  a validity mask, which is several times faster than ragged ``query_ball_point`` lists and
  lets everything after it be array arithmetic;
- scatter matrices are row-wise sums over that array, kept as six components (``sym6``);
- eigenvalues/eigenvectors of the symmetric 3x3 matrices use the closed-form trigonometric
  solution (as Open3D's ``FastEigen3x3``), several times faster than batched ``np.linalg.eigh``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from lwbench import thread_budget
from lwbench.geometry import voxel_keys

__all__ = [
    "Neighbourhood",
    "hybrid_neighbourhood",
    "gathered_moments",
    "outer6",
    "scatter",
    "trace_sym6",
    "det_sym6",
    "eigvals_sym6",
    "eigvec_sym6",
    "first_beaten",
    "local_max",
    "radius_nms",
    "row_count",
    "nms_levels",
    "voxel_downsample",
]


@dataclass(frozen=True)
class Neighbourhood:
    """Fixed-width neighbour lists: ``idx[i, j]`` is a neighbour of ``i`` where ``valid[i, j]``.

    Invalid slots hold the point itself so gathers stay in range and offsets are 0; ``dist`` is
    ``inf`` there. Column 0 is the point itself (distance 0) unless an exact duplicate ties
    with it, which gives the same offsets.
    """

    idx: np.ndarray  # (N, K) int64
    valid: np.ndarray  # (N, K) bool
    dist: np.ndarray  # (N, K) float64, distances, inf where invalid

    @property
    def count(self) -> np.ndarray:
        """Number of neighbours (including the point itself) per point."""
        return row_count(self.valid)

    def within(self, radius: float, refill: bool = True) -> Neighbourhood:
        """The sub-neighbourhood closer than ``radius`` (a smaller ball, same arrays).

        ``refill=False`` only narrows ``valid`` (cheaper): enough for NMS, which reads only the
        valid slots, but not for :func:`scatter`, which needs invalid slots to hold the point.
        """
        valid = self.valid & (self.dist < radius)
        if not refill:
            return Neighbourhood(self.idx, valid, self.dist)
        fill = self.idx[:, :1]
        return Neighbourhood(np.where(valid, self.idx, fill), valid, np.where(valid, self.dist, np.inf))


def row_count(mask: np.ndarray) -> np.ndarray:
    """True entries per row of an ``(N, K)`` bool array, int64.

    A float32 matrix-vector product (exact: counts are far below 2**24) is 3x faster than
    ``mask.sum(axis=1)`` over K = 16 columns (0.9 vs 2.7 ms at 124,668 rows).
    """
    return (mask.astype(np.float32) @ np.ones(mask.shape[1], dtype=np.float32)).astype(np.int64)


def hybrid_neighbourhood(points: np.ndarray, max_nn: int, radius: float) -> Neighbourhood:
    """The ``max_nn`` nearest points within ``radius`` of every point (itself included).

    An unbalanced, non-compacted tree builds in half the time of SciPy's defaults on a
    124k-point KITTI frame (11 vs 21 ms). ``leafsize=32`` queries fastest (k=16, 2 threads,
    medians of 7: 105 ms vs 134 ms with ``leafsize=8`` at 124,668 points, 51 vs 63 ms at
    60,152); the neighbours are the same, only equidistant ones can come in another order.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    k = int(min(max_nn, n))
    from scipy.spatial import cKDTree  # here, not at import: plugin discovery stays fast

    tree = cKDTree(pts, leafsize=32, balanced_tree=False, compact_nodes=False)
    dist, idx = tree.query(pts, k=k, distance_upper_bound=radius, workers=thread_budget())
    if k == 1:
        dist, idx = dist[:, None], idx[:, None]
    valid = idx < n
    np.copyto(idx, np.arange(n)[:, None], where=~valid)  # in place: no second (N, K) array
    return Neighbourhood(idx=idx, valid=valid, dist=dist)


#: Rows per block in :func:`gathered_moments`: a ``(3, block, K)`` float32 block stays in cache.
BLOCK = 2048

_PAIRS = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def gathered_moments(
    values: np.ndarray, idx: np.ndarray, valid: np.ndarray | None = None, centred: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Row sums ``sum_j v_j`` ``(3, N)`` and ``sum_j v_j v_j^T`` (sym6 ``(6, N)``) of gathered vectors.

    ``values`` is ``(3, M)``, coordinate-major; row ``i`` gathers ``values[:, idx[i]]``. With
    ``centred`` the vectors are offsets ``v_j - v_i`` from the row's own column (so float32
    keeps its precision far from the origin); with ``valid`` the slots where it is False read
    column ``M - 1`` instead, which the caller keeps at zero. Component order of the sym6
    output (used by every ``*_sym6`` function): xx, xy, xz, yy, yz, zz.

    Why blocks of :data:`BLOCK` rows instead of one ``(3, N, K)`` array: the gathered block
    stays in cache for the six products, and no 24 MB temporary has to be page-faulted in on
    every call -- 2x faster on a 124,668-point KITTI frame (``max_nn=16``: 23 vs 50 ms for
    :func:`scatter`). Per plane, ``np.take`` into a preallocated block is ~1.6x faster than
    ``values[:, idx]``; row sums are a matrix-vector product (10x faster than ``sum(axis=2)``
    over K = 16); products are summed in float32 (2x faster than casting every operand; K is
    small and offsets are local, so the sums keep ~7 significant digits).
    """
    vals = np.ascontiguousarray(values, dtype=np.float32)
    n, k = idx.shape
    sums = np.empty((3, n), dtype=np.float32)
    outer = np.empty((6, n), dtype=np.float32)
    buf = np.empty((3, min(BLOCK, n), k), dtype=np.float32)
    ones = np.ones(k, dtype=np.float32)
    fill = vals.shape[1] - 1
    for a in range(0, n, BLOCK):  # blocks of rows, each fully vectorized
        b = min(a + BLOCK, n)
        v = buf[:, : b - a]
        rows = idx[a:b] if valid is None else np.where(valid[a:b], idx[a:b], fill)
        for c in range(3):
            np.take(vals[c], rows, out=v[c])
            if centred:
                v[c] -= vals[c, a:b, None]
        np.matmul(v, ones, out=sums[:, a:b])
        for j, (p, q) in enumerate(_PAIRS):
            np.einsum("nk,nk->n", v[p], v[q], out=outer[j, a:b])
    return sums.astype(np.float64), outer.astype(np.float64)


def scatter(points: np.ndarray, nb: Neighbourhood) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-point neighbour statistics, in coordinates relative to the query point.

    Returns ``(count (N,), mean offset (3, N), S (6, N))`` where ``S`` is the mean-centred
    scatter matrix ``sum_j (p_j - mean)(p_j - mean)^T`` in sym6 components (float64).
    Invalid slots hold the point itself, so their offsets are 0 and add nothing.
    """
    pts = np.asarray(points, dtype=np.float32).T
    count = nb.count.astype(np.float64)
    sums, s = gathered_moments(pts, nb.idx, centred=True)
    mean = sums / np.maximum(count, 1.0)
    for a, b in _column_blocks(len(count)):  # cache-sized temporaries (4.8 -> 1.5 ms at 124k)
        s[:, a:b] -= count[a:b] * outer6(mean[:, a:b])
    return count, mean, s


def outer6(v: np.ndarray) -> np.ndarray:
    """``v v^T`` of ``(3, N)`` vectors in sym6 components ``(6, N)``."""
    x, y, z = v
    return np.stack([x * x, x * y, x * z, y * y, y * z, z * z])


def trace_sym6(m: np.ndarray) -> np.ndarray:
    return m[0] + m[3] + m[5]


def det_sym6(m: np.ndarray) -> np.ndarray:
    a, d, e, b, f, c = m
    return a * (b * c - f * f) - d * (d * c - f * e) + e * (d * f - b * e)


def eigvals_sym6(m: np.ndarray) -> np.ndarray:
    """Eigenvalues of symmetric 3x3 matrices given as sym6 ``(6, N)``, ascending ``(3, N)``.

    Closed form (Smith 1961, as Open3D's ``FastEigen3x3``): shift by the mean eigenvalue,
    scale, and read the three roots off the cosine of one angle. Multiples of the identity
    return three equal values.

    Elementwise work in column blocks of :data:`COLUMNS` (see :func:`_column_blocks`).
    """
    n = m.shape[1]
    out = np.empty((3, n), dtype=np.float64)
    for a, b in _column_blocks(n):
        out[:, a:b] = _eigvals_block(m[:, a:b])
    return out


def _eigvals_block(m: np.ndarray) -> np.ndarray:
    a, d, e, b, f, c = m
    q = (a + b + c) / 3.0
    aq, bq, cq = a - q, b - q, c - q
    p = np.sqrt((aq * aq + bq * bq + cq * cq + 2.0 * (d * d + e * e + f * f)) / 6.0)
    safe = p > 1e-300
    inv = np.where(safe, 1.0 / np.where(safe, p, 1.0), 0.0)
    r = np.clip(det_sym6(np.stack([aq, d, e, bq, f, cq]) * inv) / 2.0, -1.0, 1.0)
    phi = np.arccos(r) / 3.0
    l_max = q + 2.0 * p * np.cos(phi)
    l_min = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    l_mid = 3.0 * q - l_max - l_min
    # Rounding can swap them by ~1 ulp: a 3-element sorting network (min/max, as np.sort).
    lo, hi = np.minimum(l_min, l_mid), np.maximum(l_min, l_mid)
    mid = np.minimum(hi, l_max)
    return np.stack([np.minimum(lo, mid), np.maximum(lo, mid), np.maximum(hi, l_max)])


def eigvec_sym6(m: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit eigenvectors ``(3, N)`` of sym6 matrices for eigenvalues ``lam`` ``(N,)``, and validity.

    The eigenvector spans the null space of ``M - lam I``: the largest of the three cross
    products of its rows. Where all of them vanish (the eigenvalue is not simple, e.g. fewer
    than 3 distinct neighbours) the vector is undefined and ``valid`` is False. Computed in
    column blocks of :data:`COLUMNS` (see :func:`_column_blocks`).
    """
    n = m.shape[1]
    v = np.empty((3, n), dtype=np.float64)
    valid = np.empty(n, dtype=bool)
    for a, b in _column_blocks(n):
        v[:, a:b], valid[a:b] = _eigvec_block(m[:, a:b], lam[a:b])
    return v, valid


def _eigvec_block(m: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, d, e, b, f, c = m
    a, b, c = a - lam, b - lam, c - lam
    r0, r1, r2 = np.stack([a, d, e]), np.stack([d, b, f]), np.stack([e, f, c])
    cands = np.stack([_cross(r0, r1), _cross(r0, r2), _cross(r1, r2)])  # (3 cand, 3, N)
    norms = (cands * cands).sum(axis=1)  # (3, N)
    best = norms.argmax(axis=0)
    cols = np.arange(m.shape[1])
    v = cands[best, :, cols].T  # (3, N)
    nrm2 = norms[best, cols]
    scale = (m * m).sum(axis=0) + (m[1] ** 2 + m[2] ** 2 + m[4] ** 2)  # |M|_F^2
    valid = nrm2 > 1e-20 * np.maximum(scale, 1e-300) ** 2
    v = np.where(valid, v / np.sqrt(np.where(valid, nrm2, 1.0)), 0.0)
    return v, valid


#: Columns per block of the elementwise eigen solvers.
COLUMNS = 16384


def _column_blocks(n: int) -> Iterator[tuple[int, int]]:
    """``(start, stop)`` of column blocks for elementwise work over ``(., N)`` arrays.

    The closed-form solvers make some 40 temporaries; over 16,384 columns they stay in cache
    and freed buffers are reused, where full-length ones each cost a fresh 1 MB allocation:
    eigenvalues of a 124,668-point KITTI frame take 6-8 ms instead of 12-15 ms, same values.
    """
    return ((a, min(a + COLUMNS, n)) for a in range(0, n, COLUMNS))


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def first_beaten(response: np.ndarray, nb: Neighbourhood) -> np.ndarray:
    """Column of the nearest valid neighbour with a larger response; ``K`` where there is none.

    One pass serves every NMS in this package: a point is a local maximum over its nearest
    ``c`` neighbours exactly when ``first_beaten >= c`` (columns are sorted by distance).
    PCL and Open3D keep exact ties; here a tie goes to the lower index, so a plateau (a
    perfectly regular synthetic surface, duplicated points) yields one keypoint per
    neighbourhood rather than all of its points. Real scans have no exact ties away from
    duplicates, so their keypoints are the same.

    Computed in blocks of :data:`BLOCK` rows, whose ``(block, K)`` temporaries stay in cache
    (11 -> 8 ms on a 124,668-point KITTI frame, same result).
    """
    n, k = nb.idx.shape
    out = np.empty(n, dtype=np.int64)
    rows = np.arange(BLOCK)
    for a in range(0, n, BLOCK):  # blocks of rows, each fully vectorized
        b = min(a + BLOCK, n)
        idx = nb.idx[a:b]
        r = response[a:b, None]
        nbr = np.take(response, idx)
        beaten = (nbr > r) | ((nbr == r) & (idx < np.arange(a, b)[:, None]))
        beaten &= nb.valid[a:b]
        first = beaten.argmax(axis=1)
        out[a:b] = np.where(beaten[rows[: b - a], first], first, k)
    return out


def local_max(response: np.ndarray, nb: Neighbourhood) -> np.ndarray:
    """True where no valid neighbour has a larger response (PCL's and Open3D's NMS)."""
    return first_beaten(response, nb) == nb.idx.shape[1]


def radius_nms(points: np.ndarray, response: np.ndarray, candidates: np.ndarray, radius: float) -> np.ndarray:
    """Second NMS pass over the candidates alone, with the full radius.

    :func:`local_max` on a capped (``max_nn``) neighbourhood compares a point only with its
    ``max_nn`` nearest, which in dense parts of a scan are much closer than ``radius``, so a
    corner can leave several maxima. Dropping every candidate that has a candidate with a
    strictly larger response within ``radius`` (one ``query_pairs`` over the few candidates)
    restores the radius. Exact ties, which capped neighbourhoods produce when nearby points
    share the same ``max_nn`` neighbours, go to the lower index. Without ties, PCL's/Open3D's
    keypoints are a subset of the result, and equal to it when no neighbourhood was capped.
    """
    cand = np.flatnonzero(candidates)
    if len(cand) < 2:
        return candidates
    from scipy.spatial import cKDTree

    tree = cKDTree(np.asarray(points)[cand].astype(np.float64), leafsize=8, balanced_tree=False, compact_nodes=False)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    r = response[cand]
    a, b = pairs[:, 0], pairs[:, 1]  # query_pairs gives a < b, so b has the larger index
    ra, rb = r[a], r[b]
    beaten = np.zeros(len(cand), dtype=bool)
    beaten[a[ra < rb]] = True
    beaten[b[rb <= ra]] = True  # exact ties (identical capped neighbourhoods): lower index wins
    out = candidates.copy()
    out[cand[beaten]] = False
    return out


def nms_levels(beaten_at: np.ndarray, k: int, eligible: np.ndarray) -> np.ndarray:
    """Top-up tiers: the NMS level at which each eligible point first becomes a local maximum.

    ``beaten_at`` is :func:`first_beaten` of a ``k``-wide neighbourhood. Level 1 is a local
    maximum over its nearest ``k/2`` neighbours, level 2 over ``k/4``, ... down to 2; eligible
    points that never are get the last level + 1, others + 2. When the detector's own keypoints
    (NMS over the full ball) fall short of the budget, filling up level by level keeps the
    extra points spread over the scan like keypoints of a smaller radius, instead of piling up
    next to the strongest corners as a plain response ranking would.
    """
    cols = []
    c = k // 2
    while c >= 2:
        cols.append(c)
        c //= 2
    level = np.where(eligible, len(cols) + 1, len(cols) + 2)
    for lev, c in reversed(list(enumerate(cols, start=1))):  # coarsest last, so it wins
        level[eligible & (beaten_at >= c)] = lev
    return level


def voxel_downsample(
    points: np.ndarray, values: np.ndarray, leaf: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid of the points and mean of ``values`` per occupied voxel (PCL ``VoxelGrid``).

    Returns ``(centroids (M, 3), mean values (M,), voxel id of every input point (N,))``.
    """
    pts = np.asarray(points, dtype=np.float64)
    _, inverse = np.unique(voxel_keys(pts, leaf, anchor="scan"), return_inverse=True)
    inverse = inverse.reshape(-1)
    m = int(inverse.max()) + 1 if len(inverse) else 0
    cnt = np.bincount(inverse, minlength=m).astype(np.float64)
    cent = np.stack([np.bincount(inverse, pts[:, j], minlength=m) for j in range(3)], axis=1)
    cent /= cnt[:, None]
    val = np.bincount(inverse, np.asarray(values, dtype=np.float64), minlength=m) / cnt
    return cent, val, inverse
