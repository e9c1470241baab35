"""The ``poconet`` selection codec (the learned selector) and ``oracle`` (the true labels).

``poconet`` keeps exactly the budget (``ratio`` / ``points``, like every selector): a share of
it (``ground_share``) from the points it predicts are ground -- the paper keeps "most points
marked as high priority and some ground points" -- and the rest from the other points ranked by
the network's probability of high priority, with spatial balance
(:func:`.diagnostics.balanced_order`: round-robin over ``cell`` x ``cell`` m
cells, the best-scored point of each cell first). Version 1 took the argmax class and a random
order inside it: the kept points were only as precise as the argmax (0.26-0.29 on held-out
scans), and the probability, ranked without balance, keeps one patch (an early checkpoint's top
10,389 points on the KITTI frame all lay in one 15 m sector). Deterministic for a seed.

The default ``ground_share`` 0.1 was chosen on the validation drive (seed 20, never a Table I
seed) with the oracle at 1/12: ground_share 0 / 0.1 / 0.25 / 0.5 gave a tracking ATE of 20.8 /
4.3 / 4.6 / 5.2 mm (raw 16.0 mm, random 19.3 mm): with no ground kept, ICP has almost nothing
that fixes height, roll and pitch.

``poconet`` runs the network on at most ``points_in`` points of the scan (a seeded random
sample, RandLA-Net's own sampling) and carries each prediction to the other points by nearest
neighbour, as RandLA-Net does at test time: the first layer's 16-neighbour encoding is the cost,
and a 120k-point KITTI scan holds ~4x the points its geometry needs for a priority class.

``oracle`` reads labels written by ``lwbench label`` (``oracle.labels=DIR``) and keeps them by
:func:`.diagnostics.select_by_class` (the ground quota, high priority, ground,
the rest; random inside a class). ``oracle.precision=p`` is the *noisy oracle*: the same rule on
labels whose high-priority set is corrupted to precision ``p``
(:func:`.diagnostics.noisy_classes`), the curve ``lwbench diagnose`` draws.
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

from .diagnostics import LABEL_HIGH as HIGH
from .diagnostics import LabelFolder, ScoreFolder, noisy_classes, select_by_class, select_by_score

__all__ = [
    "PocoNetSelector",
    "OracleSelector",
    "load_checkpoint",
    "select_by_class",
    "select_by_score",
    "SHIPPED_WEIGHTS",
    "CHECKPOINT_FORMAT",
]

GROUND_SHARE = Param("ground_share", "float", 0.1, "share of the budget kept for ground points", low=0.0, high=1.0)
SHIPPED_WEIGHTS = Path(__file__).with_name("weights") / "poconet_sim_urban.pt"
CHECKPOINT_FORMAT = "lwbench-poconet"


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
        net = PocoNet(NetConfig.from_dict(cfg))
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
    version = "2"  # 2: ranked by P(high) with spatial balance (1: argmax class, random inside)
    description = "learned priority (RandLA-Net + GFA): a ground quota, then P(high) with spatial balance"
    supports_gpu = True
    params = (
        *BUDGET_PARAMS,
        Param("weights", "str", "shipped", "checkpoint: 'shipped' (trained on sim urban) or a path"),
        Param(
            "points_in",
            "int",
            None,
            "the network sees at most this many points of a scan (default: the density it was trained at)",
            low=256,
        ),
        Param(
            "seed", "int", 0, "seed of the input sample, the network's sub-sampling and the order within a class", low=0
        ),
        GROUND_SHARE,
        Param("cell", "float", 3.0, "cell size (m) of the spatial balance; 0 = plain P(high) order", low=0.0),
        Param(
            "score",
            "str",
            "p_high",
            "what ranks the non-ground points: the network's P(high), 'random' "
            "(a control: the same rule without the network's ranking) or 'file' (another model's "
            "scores from poconet.scores=DIR, e.g. the features' model of `lwbench poconet-ceiling`)",
            choices=("p_high", "random", "file"),
        ),
        Param("scores", "str", None, "folder of per-point scores (score=file)"),
        DEVICE_PARAM,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self._score_folder: ScoreFolder | None = None

    @classmethod
    def missing(cls, config: dict[str, Any]) -> str:
        if config.get("score") == "file" and not config.get("scores"):
            return "set poconet.scores=DIR with score=file (scores written by `lwbench poconet-ceiling --write-scores`)"
        return ""

    def _file_scores(self, frame: Frame) -> np.ndarray:
        if not self.config["scores"]:
            raise ParameterError(f"poconet: {self.missing(self.config)}")
        if self._score_folder is None:
            self._score_folder = ScoreFolder(self.config["scores"])
        return self._score_folder.scores(frame.index, len(frame))

    def _weights(self) -> str:
        w = self.config["weights"]
        return str(SHIPPED_WEIGHTS if w == "shipped" else Path(w).expanduser())

    def probabilities(self, frame: Frame) -> np.ndarray:
        """``(N, 3)`` class probabilities of every point of the scan (low, high, ground)."""
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
        probs = net.probabilities(logits[0]).double().cpu().numpy()
        if len(pick) == n:
            return probs
        _, nearest = cKDTree(pts).query(frame.points, k=1, workers=-1)
        return probs[nearest]

    def scores(self, frame: Frame) -> np.ndarray:
        """Per point the probability of high priority (what ``lwbench diagnose`` ranks; with
        ``score=file`` the file's scores). Right after :meth:`select` of the same scan, the
        probabilities it computed (no second pass)."""
        if self.config["score"] == "file":
            return self._file_scores(frame)
        memo = getattr(self, "_last", None)
        if memo is not None and memo[0] is frame.points and memo[1] == frame.index:
            return memo[2][:, HIGH]
        return self.probabilities(frame)[:, HIGH]

    def select(self, frame: Frame) -> np.ndarray:
        k = self.budget(len(frame))
        if k == 0 or len(frame) == 0:
            return np.empty(0, dtype=np.int64)
        probs = self.probabilities(frame)
        self._last = (frame.points, frame.index, probs)
        rng = np.random.default_rng([self.config["seed"], frame.index, 1])
        how = self.config["score"]
        score = probs[:, HIGH] if how == "p_high" else self._file_scores(frame) if how == "file" else rng.random(
            len(frame))
        return select_by_score(
            frame.points, probs.argmax(axis=1), score, k, rng, self.config["ground_share"], self.config["cell"]
        )


class OracleSelector(SelectionCodec):
    """The true labels of the sequence: high priority, then ground, then the rest."""

    name = "oracle"
    version = "2"  # 2: precision (the noisy oracle)
    description = "selects by the true PocoNet labels of the sequence (lwbench label): the upper bound"
    needs = "labels written for the sequence by `lwbench label` (oracle.labels=DIR)"
    params = (
        *BUDGET_PARAMS,
        Param("labels", "str", None, "folder written by `lwbench label`"),
        Param("seed", "int", 0, "seed of the order within a class (and of the corruption)", low=0),
        Param(
            "precision",
            "float",
            None,
            "noisy oracle: the high-priority set corrupted to this precision "
            "(same size, the rest truly low points at random)",
            low=0.0,
            high=1.0,
        ),
        Param(
            "rule",
            "str",
            "class",
            "'class': ground quota, high, ground, rest; 'score': ground quota, then "
            "the high-priority marks ranked with spatial balance (poconet's rule)",
            choices=("class", "score"),
        ),
        Param("cell", "float", 3.0, "cell size (m) of the 'score' rule's spatial balance", low=0.0),
        GROUND_SHARE,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self._labels: LabelFolder | None = None

    @classmethod
    def missing(cls, config: dict[str, Any]) -> str:
        if not config.get("labels"):
            return "set oracle.labels=DIR (labels written by `lwbench label DATASET --out DIR`)"
        return ""

    def select(self, frame: Frame) -> np.ndarray:
        if not self.config["labels"]:
            raise ParameterError(f"oracle: {self.missing(self.config)}")
        if self._labels is None:
            self._labels = LabelFolder(self.config["labels"])
        k = self.budget(len(frame))
        cls = self._labels.classes(frame.index, len(frame))
        p = self.config["precision"]
        rng = np.random.default_rng([self.config["seed"], frame.index, round(1e6 * (1.0 if p is None else p))])
        if p is not None:
            cls = noisy_classes(cls, p, rng)
        if self.config["rule"] == "score":
            return select_by_score(
                frame.points,
                cls,
                (cls == HIGH).astype(np.float64),
                k,
                rng,
                self.config["ground_share"],
                self.config["cell"],
            )
        return select_by_class(cls, k, self.config["seed"], frame.index, self.config["ground_share"])
