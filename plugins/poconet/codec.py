"""The ``poconet`` selection codec (the learned selector) and ``oracle`` (the true labels).

Both rank every point by priority class -- high priority first, then ground, then the rest --
and keep exactly the budget (``ratio`` / ``points``, like every selector), optionally with a
share of it kept for ground (``ground_share``: the paper keeps "most points marked as high
priority and some ground points"). The default 0.1 was chosen on the validation drive (seed 20,
never a Table I seed) with the oracle at 1/12: ground_share 0 / 0.1 / 0.25 / 0.5 gave a tracking
ATE of 20.8 / 4.3 / 4.6 / 5.2 mm and rotation errors of 0.067 / 0.024 / 0.020 / 0.020 deg (raw
16.0 mm, 0.012 deg; random 19.3 mm): with no ground kept, ICP has almost nothing that fixes
height, roll and pitch. Within a class the order is a seeded random one (the class is the
label; a class's points are equal): ordering by the network's probability instead keeps one
patch, because the probability is smooth in space -- measured on the KITTI frame, an early
checkpoint's top 10,389 high-priority points all lay in one 15 m sector, where a random order
spreads them over every part of the scan the network marks. Deterministic for a seed.

``poconet`` runs the network on at most ``points_in`` points of the scan (a seeded random
sample, RandLA-Net's own sampling) and carries each prediction to the other points by nearest
neighbour, as RandLA-Net does at test time: the first layer's 16-neighbour encoding is the cost,
and a 120k-point KITTI scan holds ~4x the points its geometry needs for a priority class.

``oracle`` reads labels written by ``lwbench label`` (``oracle.labels=DIR``): what the network
learns toward, computed with the whole sequence and its ground truth -- an upper bound no
single-scan method can reach, and a row no paper shows.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from lwbench import (
    BUDGET_PARAMS,
    DEVICE_PARAM,
    DataFormatError,
    Frame,
    Param,
    ParameterError,
    SelectionCodec,
    resolve_device,
)

from .labels import GROUND, HIGH, LOW, LabelStore

__all__ = ["PocoNetSelector", "OracleSelector", "load_checkpoint", "SHIPPED_WEIGHTS", "CHECKPOINT_FORMAT"]

GROUND_SHARE = Param("ground_share", "float", 0.1, "share of the budget kept for ground points", low=0.0, high=1.0)
SHIPPED_WEIGHTS = Path(__file__).with_name("weights") / "poconet_sim_urban.pt"
CHECKPOINT_FORMAT = "lwbench-poconet"


def select_by_class(cls: np.ndarray, k: int, seed: int, index: int, ground_share: float = 0.0) -> np.ndarray:
    """The budget by class: high priority, then ground, then the rest, with ``ground_share`` of
    the budget kept for ground points ("most points marked as high priority and some ground
    points", §III-A); a seeded random order within a class where its quota runs out."""
    k = int(min(k, len(cls)))
    order = np.random.default_rng([seed, index, 1]).permutation(len(cls))
    high, ground, rest = (order[cls[order] == c] for c in (HIGH, GROUND, LOW))
    reserved = min(len(ground), round(ground_share * k))
    n_high = min(len(high), k - reserved)
    n_ground = min(len(ground), k - n_high)
    keep = np.concatenate([high[:n_high], ground[:n_ground], rest[: k - n_high - n_ground]])
    return np.sort(keep).astype(np.int64)


@functools.lru_cache(maxsize=4)
def load_checkpoint(path: str, device: str):
    """The network of a PocoNet checkpoint (``torch.load(weights_only=True)``: no code runs)."""
    import torch

    from .network import NetConfig, PocoNet

    p = Path(path)
    if not p.is_file():
        raise DataFormatError(f"poconet: no checkpoint at {p}")
    try:
        ckpt = torch.load(p, map_location=device, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - torch raises many types for a bad file
        raise DataFormatError(f"poconet: {p} is not a readable checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise DataFormatError(f"poconet: {p} is not a PocoNet checkpoint (format {CHECKPOINT_FORMAT!r} expected)")
    try:
        cfg = ckpt["config"]
        net = PocoNet(NetConfig(**{**cfg, "d_out": tuple(cfg["d_out"])}))
        net.load_state_dict(ckpt["model"])
    except (KeyError, TypeError, RuntimeError) as exc:
        raise DataFormatError(f"poconet: {p} does not match the network ({exc})") from None
    net.to(device).eval()
    return net, ckpt.get("meta", {})


def trained_points_in(meta: dict) -> int:
    """The sample size a checkpoint was trained with: the neighbourhoods the network learned
    are those of that density, so inference samples a scan to the same count."""
    return int(meta.get("train", {}).get("points_in", 16384))


class PocoNetSelector(SelectionCodec):
    """The points PocoNet predicts matter for localization (Cui et al., §III)."""

    name = "poconet"
    version = "1"
    description = "learned priority classes (RandLA-Net + GFA); keeps high priority, then ground"
    supports_gpu = True
    params = (
        *BUDGET_PARAMS,
        Param("weights", "str", "shipped", "checkpoint: 'shipped' (trained on sim urban) or a path"),
        Param("points_in", "int", None, "the network sees at most this many points of a scan "
              "(default: the density it was trained at)", low=256),
        Param("seed", "int", 0, "seed of the input sample, the network's sub-sampling and the order within a class",
              low=0),
        GROUND_SHARE,
        DEVICE_PARAM,
    )

    def _weights(self) -> str:
        w = self.config["weights"]
        return str(SHIPPED_WEIGHTS if w == "shipped" else Path(w).expanduser())

    def probabilities(self, frame: Frame) -> np.ndarray:
        """``(N, 3)`` class probabilities of every point of the scan."""
        import torch
        from scipy.spatial import cKDTree

        from .data import features, prepare, to_torch

        device = resolve_device(self.config["device"])
        net, meta = load_checkpoint(self._weights(), str(device))
        cfg = net.config
        n = len(frame)
        rng = np.random.default_rng([self.config["seed"], frame.index])
        cap = self.config["points_in"] or trained_points_in(meta)
        pick = np.sort(rng.choice(n, cap, replace=False)) if n > cap else np.arange(n)
        pts = frame.points[pick]
        feats = features(frame)[pick]
        pyramid = prepare(pts, cfg.k, cfg.ratio, len(cfg.d_out), rng)
        with torch.no_grad():
            logits, _ = net(to_torch([pyramid], [feats], device))
        probs = torch.softmax(logits[0], dim=-1).double().cpu().numpy()
        if len(pick) == n:
            return probs
        _, nearest = cKDTree(pts).query(frame.points, k=1, workers=-1)
        return probs[nearest]

    def select(self, frame: Frame) -> np.ndarray:
        k = self.budget(len(frame))
        if k == 0 or len(frame) == 0:
            return np.empty(0, dtype=np.int64)
        cls = self.probabilities(frame).argmax(axis=1)
        return select_by_class(cls, k, self.config["seed"], frame.index, self.config["ground_share"])


class OracleSelector(SelectionCodec):
    """The true labels of the sequence: high priority, then ground, then the rest."""

    name = "oracle"
    version = "1"
    description = "selects by the true PocoNet labels of the sequence (lwbench label): the upper bound"
    needs = "labels written for the sequence by `lwbench label` (oracle.labels=DIR)"
    params = (
        *BUDGET_PARAMS,
        Param("labels", "str", None, "folder written by `lwbench label`"),
        Param("seed", "int", 0, "seed of the order within a class", low=0),
        GROUND_SHARE,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self._store = LabelStore(self.config["labels"]) if self.config["labels"] else None

    def select(self, frame: Frame) -> np.ndarray:
        if self._store is None:
            raise ParameterError("oracle: set oracle.labels=DIR (labels written by `lwbench label DATASET --out DIR`)")
        k = self.budget(len(frame))
        labels, _ = self._store.read(frame.index, len(frame))
        return select_by_class(labels, k, self.config["seed"], frame.index, self.config["ground_share"])
