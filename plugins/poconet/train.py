"""Training PocoNet on simulated streets (``lwbench train poconet``), on the CPU or a GPU.

- **Data**: two-day ``sim`` drives (``traversals=2``: a mapping drive, then a drive on another
  day with other parked cars, as Table I's), several scenes and seeds (``drives``: urban seeds
  30-51, two indoor and two tunnel drives; Table I's seeds 100-104 and the validation seed 20 are
  others), HDL-64E with 2 cm range noise and motion distortion on the street (the localization
  protocol's settings). Labelled once by :func:`~.labels.label_dataset` with the labels the
  evaluation uses (``counts_from``, default ``"mapping"``: counts from the mapping drive only,
  what a robot could have) and kept in ``OUT/labels/SCENE-SEED`` (resumable). Both days train,
  each drive without ``margin`` scans at either end (:func:`_middle`).
- **Samples**: each scan sampled to ``points_in`` points (what the codec feeds the network) and
  fed whole (``sample="whole"``; the paper feeds the whole scan) or as a crop of ``crop`` points
  around a random point (``sample="crop"``, the first checkpoint's); two independent random
  samplings of the hierarchy make the siamese pair.
- **Intensity dropout**: half the samples have their intensity zeroed, which is what a scan
  without intensity (KITTI odometry's x, y, z files, many bags) looks like to the network.
- **Heading** (:func:`augment_heading`): a mirror across x-z half the time and a yaw jitter of
  ``yaw_jitter_deg`` (10°), so the network keeps the driving direction, which the labels depend
  on (counts accumulate along the path); ``heading="full"`` is the first checkpoint's random yaw.
- **Loss** (the paper's): one binary cross-entropy per class plus ``lam`` times the codewords'
  squared L2 distance (:func:`~.network.siamese_loss`), on a normalized codeword
  (:class:`~.network.GlobalFeatureAttention` says why); Adam, lr ``1e-3`` decayed 5 % per epoch.
  ``var_weight`` adds VICReg's variance term against the last ``var_bank`` scans' codewords
  (:func:`~.network.variance_loss`), tried and not kept: off by default (docs/poconet.md).
- **Threads**: ``threads`` torch threads (default 1): on this shared 2-core CPU one
  forward+backward of a siamese pair took 0.67 s on one thread and 5.9 s on two while other jobs
  ran (two threads wait on each other when a core is taken).
- **Weight average**: what is evaluated and exported is an exponential moving average of the
  steps' weights (``ema``, see :class:`_Averaged` for the measured reason).
- **Checkpoints** after every epoch (``OUT/last.pt`` with the optimiser state, so a killed run
  resumes; ``OUT/epoch-NNN.pt``), and the learning curve in ``OUT/curve.jsonl``: losses, the
  validation scans' AUC of P(high), top-k precision, per-class accuracy and IoU, and the global
  module's swap/zero ablation (:func:`gfa_ablation`). ``export`` writes the small weights-only
  file the codec ships with.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from lwbench import Dataset, ParameterError, open_dataset

from .codec import CHECKPOINT_FORMAT
from .data import crop, features, prepare, to_torch
from .diagnostics import LABEL_GROUND as GROUND
from .diagnostics import LABEL_HIGH as HIGH
from .diagnostics import roc_auc, top_k_precision
from .labels import CLASSES, COUNTS_FROM, LabelSettings, LabelStore, label_dataset
from .network import NetConfig, PocoNet, siamese_loss, variance_loss

__all__ = ["TrainConfig", "train", "export", "evaluate_scans", "gfa_ablation", "parse_drives", "SIM_PROTOCOL"]

# The street and sensor the shipped weights are trained and evaluated on (issue 14 protocol):
# two drives, the second on another day.
SIM_PROTOCOL = {"noise": 0.02, "distortion": True, "traversals": 2}
DEFAULT_DRIVES = (*(f"urban:{s}" for s in range(30, 52)), "indoor:30", "indoor:31", "tunnel:30", "tunnel:31")
NET = NetConfig(output="sigmoid", context="points").as_dict()


@dataclass
class TrainConfig:
    out: str
    drives: tuple[str, ...] = DEFAULT_DRIVES  # "scene:seed"
    val_drives: tuple[str, ...] = ("urban:20",)
    frames: int = 40  # per drive; two drives (days) per seed
    margin: int = 10  # scans at each end of each drive that only count observations
    val_frames: int = 8  # per drive of a validation seed
    counts_from: str = "mapping"
    epochs: int = 4
    sample: str = "whole"  # "whole": the points_in sample of the scan; "crop": crop points of it
    crop: int = 8192
    points_in: int = 16384
    lr: float = 1e-3
    decay: float = 0.95
    lam: float = 1.0
    var_weight: float = 0.0  # VICReg's variance term on the codeword (0: the paper's loss alone)
    var_bank: int = 32  # recent scans' codewords it measures the spread against
    ema: float = 0.998  # the exported weights: a moving average of the steps' (0: the last step's)
    binary: bool = True  # the paper's binary cross-entropy (False: the 3-class weighted one)
    intensity_dropout: float = 0.5
    heading: str = "jitter"  # "jitter": mirror + yaw jitter; "full": any yaw + mirror; "none"
    yaw_jitter_deg: float = 10.0
    seed: int = 0
    time_budget_s: float | None = None
    device: str = "auto"
    threads: int = 1
    net: dict = field(default_factory=lambda: dict(NET))


def parse_drives(text: str) -> tuple[str, ...]:
    """``"urban:30-51,indoor:30"`` -> ``("urban:30", ..., "urban:51", "indoor:30")``."""
    out = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        scene, sep, seeds = part.partition(":")
        lo, dash, hi = seeds.partition("-")
        if not sep or not lo.isdigit() or (dash and not hi.isdigit()):
            raise ParameterError(f"train poconet: a drive is SCENE:SEED or SCENE:FIRST-LAST, got {part!r}")
        out += [f"{scene}:{s}" for s in range(int(lo), int(hi if dash else lo) + 1)]
    return tuple(out)


def _sim(drive: str, frames: int) -> Dataset:
    scene, _, seed = drive.partition(":")
    return open_dataset("sim", {**SIM_PROTOCOL, "scene": scene, "seed": int(seed), "frames": frames})


def _labelled(ds: Dataset, folder: Path, settings: LabelSettings) -> LabelStore:
    store = LabelStore(folder)
    try:
        meta = store.meta()
        if meta["dataset"] == ds.identity() and meta["settings"] == settings.__dict__:
            return store
    except Exception:  # noqa: BLE001 - not there yet, or stale: label again
        pass
    labels, counts = label_dataset(ds, settings=settings)
    store.write(ds, list(range(len(ds))), labels, counts, settings)
    return store


def _class_weights(stores: list[tuple[Dataset, LabelStore]]) -> np.ndarray:
    counts = np.zeros(len(CLASSES))
    for ds, store in stores:
        meta = store.meta()
        for i in range(len(ds)):
            lab, _ = store.read(i, meta["frames"][str(i)])
            counts += np.bincount(lab, minlength=len(CLASSES))
    freq = counts / counts.sum()
    w = 1.0 / (freq + 0.02)  # RandLA-Net's weights; 1/sqrt(frequency) left high priority unlearned
    return w / w.mean()


def augment_heading(
    points: np.ndarray, rng: np.random.Generator, heading: str = "jitter", jitter_deg: float = 10.0
) -> np.ndarray:
    """A mirror across x-z half the time and a rotation about the sensor's z axis: within
    ``±jitter_deg`` (``"jitter"``), any (``"full"``), or none (``"none"``, no mirror either).

    Why not any yaw: the labels count observations along the drive, so how a surface lies to the
    driving direction (x in every sensor frame here and in KITTI's) is part of what they mean; a
    gradient-boosted tree on 11 local features gained +0.04-0.07 AUC from azimuth and lateral
    position. Why a mirror: a street is the same seen from its other lane, and the simulated car
    always keeps to one side of it (the first checkpoint, without any augmentation, marked
    every KITTI point beyond y = 8 m high priority)."""
    if heading == "none":
        return np.asarray(points, np.float32)
    a = rng.uniform(0, 2 * np.pi) if heading == "full" else np.deg2rad(rng.uniform(-jitter_deg, jitter_deg))
    c, s = np.cos(a), np.sin(a)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
    if rng.random() < 0.5:
        rot = rot @ np.diag([1.0, -1.0, 1.0]).astype(np.float32)
    return (points @ rot.T).astype(np.float32)


def _sample(points_in: int, n: int, rng: np.random.Generator) -> np.ndarray:
    return np.sort(rng.choice(n, points_in, replace=False)) if n > points_in else np.arange(n)


def _forward(net, pts: np.ndarray, feats: np.ndarray, device, rng: np.random.Generator, codeword=None):
    cfg = net.config
    return net(to_torch([prepare(pts, cfg.k, cfg.ratio, len(cfg.d_out), rng)], [feats], device), codeword)


def evaluate_scans(
    net, scans: list[tuple[np.ndarray, np.ndarray, np.ndarray]], device, seed: int = 0
) -> dict[str, float]:
    """On whole (sampled) scans: the AUC of P(high) among the truly non-ground points, its
    precision over the base-rate share of best scores, per-class accuracy (recall) and IoU."""
    import torch

    conf = np.zeros((len(CLASSES), len(CLASSES)), dtype=np.int64)
    aucs, hits, tops = [], 0, 0
    net.eval()
    with torch.no_grad():
        for k, (pts, feats, lab) in enumerate(scans):
            logits, _ = _forward(net, pts, feats, device, np.random.default_rng([seed, k]))
            prob = net.probabilities(logits[0]).cpu().numpy()
            np.add.at(conf, (lab, prob.argmax(-1)), 1)
            rest = lab != GROUND
            pos = lab[rest] == HIGH
            aucs.append(roc_auc(prob[rest, HIGH], pos))
            n_top = int(pos.sum())
            hits += round(top_k_precision(prob[rest, HIGH], pos, n_top) * n_top) if n_top else 0
            tops += n_top
    net.train()
    out = {"auc_high": float(np.nanmean(aucs)), "top_k_precision": hits / max(1, tops)}
    for c, name in enumerate(CLASSES):
        tp = conf[c, c]
        out[f"acc_{name.replace(' ', '_')}"] = float(tp / max(1, conf[c].sum()))
        out[f"iou_{name.replace(' ', '_')}"] = float(tp / max(1, conf[c].sum() + conf[:, c].sum() - tp))
    out["miou"] = float(np.mean([out[f"iou_{n.replace(' ', '_')}"] for n in CLASSES]))
    return out


def gfa_ablation(net, scans: list[tuple[np.ndarray, np.ndarray, np.ndarray]], device, seed: int = 0) -> dict:
    """Does the global module do anything? Each scan's prediction with its own codeword, with
    the codeword of another scan (half the list further: the other day, another place), and
    with a zero codeword; the share of points whose predicted class changes, the mean absolute change of
    P(high), and the AUC of P(high) in each case (the same hierarchy sampling throughout)."""
    import torch

    if len(scans) < 2:
        return {}
    net.eval()
    with torch.no_grad():
        codes = [_forward(net, p, f, device, np.random.default_rng([seed, k]))[1] for k, (p, f, _) in enumerate(scans)]
        acc: dict[str, list] = {
            "own_auc": [],
            "swap_auc": [],
            "zero_auc": [],
            "swap_changed": [],
            "zero_changed": [],
            "swap_dp": [],
            "zero_dp": [],
        }
        for k, (pts, feats, lab) in enumerate(scans):
            rest = lab != GROUND
            outs = {}
            for case, code in (
                ("own", None),
                ("swap", codes[(k + len(scans) // 2 + 1) % len(scans)]),
                ("zero", torch.zeros_like(codes[k])),
            ):
                logits, _ = _forward(net, pts, feats, device, np.random.default_rng([seed, k]), code)
                outs[case] = net.probabilities(logits[0]).cpu().numpy()
                acc[f"{case}_auc"].append(roc_auc(outs[case][rest, HIGH], lab[rest] == HIGH))
            for case in ("swap", "zero"):
                acc[f"{case}_changed"].append(float((outs[case].argmax(1) != outs["own"].argmax(1)).mean()))
                acc[f"{case}_dp"].append(float(np.abs(outs[case][:, HIGH] - outs["own"][:, HIGH]).mean()))
    net.train()
    return {f"gfa_{k}": float(np.nanmean(v)) for k, v in acc.items()}


def _middle(cfg: TrainConfig, ds: Dataset) -> list[int]:
    """The frames a drive trains on: each day's drive without ``margin`` scans at either end,
    whose counts are cut short by where the sequence stops (a point behind the first pose is
    seen by few poses because the drive ends, not because of what it is) -- no scan shows that."""
    return [i for t in ds.traversals() for i in t[cfg.margin : len(t) - cfg.margin]]


def _val_scans(cfg: TrainConfig, out: Path, settings: LabelSettings) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    scans = []
    for drive in cfg.val_drives:
        ds = _sim(drive, cfg.frames)
        store = _labelled(ds, out / "labels" / drive.replace(":", "-"), settings)
        for t in ds.traversals():
            middle = t[cfg.margin : len(t) - cfg.margin]
            for j in np.linspace(0, len(middle) - 1, cfg.val_frames).round().astype(int):
                i = middle[j]
                f = ds[i]
                lab, _ = store.read(i, len(f))
                pick = _sample(cfg.points_in, len(f), np.random.default_rng([cfg.seed, 7, i]))
                scans.append((f.points[pick].astype(np.float32), features(f)[pick], lab[pick].astype(np.int64)))
    return scans


class _Averaged:
    """An exponential moving average of the network's weights, what is evaluated and exported.
    Measured reason: with one scan pair per Adam step, the validation AUC of P(high) of one run
    swung 0.66 / 0.66 / 0.63 / 0.66 / 0.74 over five consecutive epochs (8 drives, crops), so
    the last step's weights are a draw from that range; the average is not."""

    def __init__(self, net, decay: float, state: dict | None = None) -> None:
        import copy

        self.decay = decay
        self.model = copy.deepcopy(net)
        if state is not None:
            self.model.load_state_dict(state)
        for p in self.model.parameters():
            p.requires_grad_(False)

    def update(self, net) -> None:
        import torch

        with torch.no_grad():
            for avg, p in zip(self.model.parameters(), net.parameters(), strict=True):
                avg.lerp_(p, 1.0 - self.decay)


def _check(cfg: TrainConfig) -> None:
    if cfg.counts_from not in COUNTS_FROM:
        raise ParameterError(f"train poconet: counts_from {cfg.counts_from!r} is not one of {COUNTS_FROM}")
    if cfg.sample not in ("whole", "crop") or cfg.heading not in ("jitter", "full", "none"):
        raise ParameterError(f"train poconet: sample {cfg.sample!r} / heading {cfg.heading!r} unknown")
    if cfg.frames - 2 * cfg.margin < 1:
        raise ParameterError(f"train poconet: margin {cfg.margin} at each end leaves none of {cfg.frames} scans")


def train(cfg: TrainConfig, progress: Callable[[str, int, int], None] | None = None) -> Path:
    """Train (or resume) into ``cfg.out``; returns the path of the last checkpoint."""
    import torch

    from lwbench import resolve_device

    _check(cfg)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)
    if device.type == "cpu":
        torch.set_num_threads(max(1, cfg.threads))
    torch.manual_seed(cfg.seed)
    net_cfg = NetConfig.from_dict(cfg.net)
    net = PocoNet(net_cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=cfg.decay)
    start_epoch, elapsed = 0, 0.0
    last = out / "last.pt"
    if last.exists():
        state = torch.load(last, map_location=device, weights_only=True)
        net.load_state_dict(state["raw_model"] if "raw_model" in state else state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        start_epoch, elapsed = int(state["epoch"]), float(state["elapsed_s"])
        if "torch_rng" in state:  # dropout goes on as if never stopped
            torch.set_rng_state(state["torch_rng"].cpu())
    averaged = _Averaged(net, cfg.ema, state["model"] if last.exists() else None)
    (out / "config.json").write_text(json.dumps(asdict(cfg), indent=1))

    settings = LabelSettings(counts_from=cfg.counts_from)
    t_labels = time.perf_counter()
    stores = []
    for n, drive in enumerate(cfg.drives):
        if progress:
            progress(f"labelling sim {drive}", n, len(cfg.drives))
        ds = _sim(drive, cfg.frames)
        stores.append((ds, _labelled(ds, out / "labels" / drive.replace(":", "-"), settings)))
    weights = None if cfg.binary else torch.as_tensor(_class_weights(stores), dtype=torch.float32, device=device)
    val = _val_scans(cfg, out, settings)
    labels_s = time.perf_counter() - t_labels
    samples = [(d, s, i) for d, s in stores for i in _middle(cfg, d)]
    t_start = time.perf_counter() - elapsed
    for epoch in range(start_epoch, cfg.epochs):
        rng = np.random.default_rng([cfg.seed, epoch])
        order = rng.permutation(len(samples))
        losses, bank = [], []
        for step, k in enumerate(order):
            if cfg.time_budget_s is not None and time.perf_counter() - t_start > cfg.time_budget_s:
                break
            ds, store, i = samples[k]
            f = ds[i]
            lab, _ = store.read(i, len(f))
            pick = _sample(cfg.points_in, len(f), rng)
            pts, feats, lab = f.points[pick].astype(np.float32), features(f)[pick], lab[pick]
            if cfg.sample == "crop":
                sel = crop(len(pts), cfg.crop, pts, rng)
                pts, feats, lab = pts[sel], feats[sel], lab[sel]
            if rng.random() < cfg.intensity_dropout:
                feats[:, 3] = 0.0  # a scan without intensity (KITTI's odometry .bin) is the same input
            pts = augment_heading(pts, rng, cfg.heading, cfg.yaw_jitter_deg)
            feats[:, :3] = pts
            (l1, c1), (l2, c2) = (_forward(net, pts, feats, device, rng) for _ in range(2))
            target = torch.as_tensor(lab.astype(np.int64), device=device).unsqueeze(0)
            loss, parts = siamese_loss((l1, l2), (c1, c2), target, weights, cfg.lam, binary=cfg.binary)
            if cfg.var_weight > 0:
                l_var = variance_loss(c1, bank)
                loss = loss + cfg.var_weight * l_var
                parts["variance"] = float(l_var.detach())
                bank = [c1.detach(), *bank][: cfg.var_bank]
            opt.zero_grad()
            loss.backward()
            opt.step()
            averaged.update(net)
            losses.append(parts)
            if progress:
                progress(f"epoch {epoch + 1}/{cfg.epochs} loss {parts['loss']:.3f}", step + 1, len(order))
        sched.step()
        record = {
            "epoch": epoch + 1,
            "steps": len(losses),
            "elapsed_s": time.perf_counter() - t_start,
            "labels_s": labels_s,
            "lr": opt.param_groups[0]["lr"],
            **{
                k: float(np.mean([p.get(k, math.nan) for p in losses])) if losses else math.nan
                for k in ("loss", "label", "global", "variance")
            },
            **{
                f"raw_{k}": v
                for k, v in evaluate_scans(net, val, device).items()
                if k in ("auc_high", "top_k_precision")
            },
            **evaluate_scans(averaged.model, val, device),
            **gfa_ablation(averaged.model, val, device),
        }
        with open(out / "curve.jsonl", "a") as fh:
            fh.write(json.dumps(record) + "\n")
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": net_cfg.as_dict(),
            "model": averaged.model.state_dict(),
            "raw_model": net.state_dict(),
            "torch_rng": torch.get_rng_state(),
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
            "epoch": epoch + 1,
            "elapsed_s": record["elapsed_s"],
            "meta": {"train": asdict(cfg), "curve": record},
        }
        torch.save(state, out / f"epoch-{epoch + 1:03d}.pt")
        torch.save(state, last)
        if cfg.time_budget_s is not None and record["elapsed_s"] > cfg.time_budget_s:
            break
    return last


def export(checkpoint: str | Path, dest: str | Path) -> Path:
    """The weights-only file the codec ships: network config, parameters, provenance."""
    import torch

    state = torch.load(checkpoint, map_location="cpu", weights_only=True)
    small = {
        "format": CHECKPOINT_FORMAT,
        "config": state["config"],
        "model": {k: v.detach().clone() for k, v in state["model"].items()},
        "meta": state.get("meta", {}),
    }
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    torch.save(small, dest)
    return dest
