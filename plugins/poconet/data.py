"""The data pipeline: per scan, the index structures the network gathers with.

RandLA-Net's hierarchy, computed with SciPy's ``cKDTree`` on the CPU (so the model itself has no
compiled extension): at each layer the ``k`` nearest neighbours of every point; a random
sub-sample of ``1/ratio`` of them for the next layer (whose points max-pool their neighbours);
and, for up-sampling, each point's nearest point of the next layer.

Features: x, y, z and intensity (scaled to [0, 1] per scan; 0 where a scan has none).
Training uses fixed-size crops (the ``n`` points nearest a random point of the scan, as
RandLA-Net does); inference runs the whole scan.
"""

from __future__ import annotations

import numpy as np
import torch

from lwbench import Frame

__all__ = ["features", "prepare", "to_torch", "crop"]


def features(frame: Frame) -> np.ndarray:
    """``(N, 4)`` float32: x, y, z, intensity scaled to [0, 1] (0 without intensity)."""
    inten = frame.intensity
    if inten is None or len(inten) == 0:
        i = np.zeros(len(frame), np.float32)
    else:
        i = np.asarray(inten, np.float32)
        top = float(np.percentile(i, 99)) if len(i) else 1.0
        i = np.clip(i / top, 0.0, 1.0) if top > 0 else np.zeros_like(i)
    return np.column_stack([frame.points, i]).astype(np.float32)


def _knn(points: np.ndarray, queries: np.ndarray, k: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    k = min(k, len(points))
    _, idx = cKDTree(points, leafsize=32, balanced_tree=False, compact_nodes=False).query(queries, k=k, workers=-1)
    idx = idx.reshape(len(queries), k)
    return idx.astype(np.int64)


def prepare(points: np.ndarray, k: int, ratio: int, layers: int, rng: np.random.Generator) -> dict[str, list]:
    """The index pyramid of one point set: per layer ``xyz``, ``neigh`` (k nearest), ``sub``
    (the sampled points' neighbours, into the layer) and ``interp`` (each point's nearest in
    the next layer). The random sub-sampling is drawn from ``rng`` (a siamese pair uses two)."""
    xyz = [np.asarray(points, np.float32)]
    neigh, sub, interp = [], [], []
    for _ in range(layers):
        cur = xyz[-1]
        nb = _knn(cur, cur, k)
        if nb.shape[1] < k:  # fewer points than k: repeat the nearest
            nb = np.concatenate([nb, np.repeat(nb[:, :1], k - nb.shape[1], axis=1)], axis=1)
        n_next = max(1, len(cur) // ratio)
        pick = np.sort(rng.choice(len(cur), n_next, replace=False))
        neigh.append(nb)
        sub.append(nb[pick])
        nxt = cur[pick]
        interp.append(_knn(nxt, cur, 1))
        xyz.append(nxt)
    return {"xyz": xyz, "neigh": neigh, "sub": sub, "interp": interp}


def to_torch(pyramids: list[dict[str, list]], feats: list[np.ndarray], device: torch.device) -> dict:
    """Stack equally sized pyramids into one batch of tensors."""
    out: dict = {}
    for key in ("xyz", "neigh", "sub", "interp"):
        out[key] = [
            torch.as_tensor(np.stack([p[key][layer] for p in pyramids]), device=device)
            for layer in range(len(pyramids[0][key]))
        ]
    out["features"] = torch.as_tensor(np.stack(feats), device=device)
    return out


def crop(n_points: int, size: int, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices of a fixed-size crop: the ``size`` points nearest a random point (with
    repetition when the scan is smaller, as the paper duplicates points to a fixed count)."""
    if n_points <= size:
        extra = rng.choice(n_points, size - n_points, replace=True) if size > n_points else np.empty(0, np.int64)
        return np.concatenate([np.arange(n_points), extra]).astype(np.int64)
    centre = points[rng.integers(n_points)]
    d2 = np.einsum("ij,ij->i", points - centre, points - centre)
    return np.argpartition(d2, size - 1)[:size].astype(np.int64)
