"""Training PocoNet on simulated streets (``lwbench train poconet``), on the CPU or a GPU.

- **Data**: ``sim`` urban drives of ``frames`` scans (several seeds; the evaluation seeds are
  others), HDL-64E with 2 cm range noise and motion distortion (the localization protocol's
  settings), labelled by :func:`~.labels.label_dataset` over the whole drive once and kept in
  ``OUT/labels/seed-N`` (resumable). Training uses the drive's middle: ``margin`` scans at each
  end only count observations (see :func:`_middle`; on 40-scan drives, all ends, high-priority
  accuracy stayed at 1 % after five epochs).
- **Samples**: each scan is sampled to ``points_in`` points (what the codec feeds the network),
  then a fixed-size crop of ``crop`` points around a random point (RandLA-Net's crops); two
  independent random samplings of the crop's hierarchy make the siamese pair.
- **Intensity dropout**: half the crops have their intensity zeroed, which is what a scan without
  intensity (KITTI odometry's x, y, z files, many bags) looks like to the network; otherwise it
  would meet such scans only at test time, and intensity scales differ between sensors anyway.
- **Heading augmentation**: each crop turned by a random yaw (and mirrored half the time), see
  :func:`augment_yaw`.
- **Optimisation** (the paper's): Adam, learning rate ``1e-3`` decayed by 5 % after each epoch;
  class-weighted cross-entropy (RandLA-Net's ``1 / (frequency + 0.02)``: the labels are
  imbalanced, ~1/12 high priority) plus ``lam`` times the codewords' L2 distance.
- **Checkpoints** after every epoch (``OUT/last.pt`` with the optimiser state, so a killed run
  resumes; ``OUT/epoch-NNN.pt``), and the learning curve in ``OUT/curve.jsonl``: loss, per-class
  accuracy and IoU on held-out scans. ``export`` writes the small weights-only file the codec
  ships with.
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
from .labels import CLASSES, LabelSettings, LabelStore, label_dataset
from .network import NetConfig, PocoNet, siamese_loss

__all__ = ["TrainConfig", "train", "export", "evaluate_scans", "SIM_PROTOCOL"]

# The street and sensor the shipped weights are trained and evaluated on (issue 14 protocol).
SIM_PROTOCOL = {"scene": "urban", "noise": 0.02, "distortion": True}


@dataclass
class TrainConfig:
    out: str
    train_seeds: tuple[int, ...] = (10, 11, 12, 13)
    val_seeds: tuple[int, ...] = (20,)
    frames: int = 120
    margin: int = 25
    val_frames: int = 8
    epochs: int = 12
    crop: int = 8192
    points_in: int = 16384
    lr: float = 1e-3
    decay: float = 0.95
    lam: float = 1.0
    intensity_dropout: float = 0.5
    rotate: bool = True
    seed: int = 0
    time_budget_s: float | None = None
    device: str = "auto"
    net: dict = field(default_factory=lambda: NetConfig().as_dict())


def _sim(seed: int, frames: int) -> Dataset:
    return open_dataset("sim", {**SIM_PROTOCOL, "seed": seed, "frames": frames})


def _labelled(ds: Dataset, folder: Path) -> LabelStore:
    store = LabelStore(folder)
    try:
        meta = store.meta()
        if meta["dataset"] == ds.identity() and meta["settings"] == LabelSettings().__dict__:
            return store
    except Exception:  # noqa: BLE001 - not there yet, or stale: label again
        pass
    labels, counts = label_dataset(ds, settings=LabelSettings())
    store.write(ds, list(range(len(ds))), labels, counts, LabelSettings())
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


def augment_yaw(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random rotation about the sensor's z axis and, half the time, a mirror across x-z.

    The simulated street always runs along x with the car in one lane, and x, y, z are input
    features: without this the network learns *where* in the sensor frame a façade lies (the
    first checkpoint marked every point beyond y = 8 m high priority on the KITTI frame). A
    point's label does not change with the scan's heading, so the network should not either."""
    a = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(a), np.sin(a)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
    if rng.random() < 0.5:
        rot = rot @ np.diag([1.0, -1.0, 1.0]).astype(np.float32)
    return (points @ rot.T).astype(np.float32)


def _sample(points_in: int, n: int, rng: np.random.Generator) -> np.ndarray:
    return np.sort(rng.choice(n, points_in, replace=False)) if n > points_in else np.arange(n)


def evaluate_scans(net, scans: list[tuple[np.ndarray, np.ndarray, np.ndarray]], cfg: NetConfig, device,
                   seed: int = 0) -> dict[str, float]:
    """Per-class accuracy (recall) and IoU of the predicted labels on whole (sampled) scans."""
    import torch

    conf = np.zeros((len(CLASSES), len(CLASSES)), dtype=np.int64)
    net.eval()
    with torch.no_grad():
        for k, (pts, feats, lab) in enumerate(scans):
            rng = np.random.default_rng([seed, k])
            logits, _ = net(to_torch([prepare(pts, cfg.k, cfg.ratio, len(cfg.d_out), rng)], [feats], device))
            pred = logits[0].argmax(-1).cpu().numpy()
            np.add.at(conf, (lab, pred), 1)
    net.train()
    out = {}
    for c, name in enumerate(CLASSES):
        tp = conf[c, c]
        out[f"acc_{name.replace(' ', '_')}"] = float(tp / max(1, conf[c].sum()))
        out[f"iou_{name.replace(' ', '_')}"] = float(tp / max(1, conf[c].sum() + conf[:, c].sum() - tp))
    out["miou"] = float(np.mean([out[f"iou_{n.replace(' ', '_')}"] for n in CLASSES]))
    return out


def _middle(cfg: TrainConfig) -> range:
    """The frames a drive trains on: all but ``margin`` at each end, whose counts are cut short
    by the drive's end (a point behind the first pose is seen by few poses because the
    sequence stops, not because of what it is) -- no single scan can tell that."""
    return range(cfg.margin, cfg.frames - cfg.margin)


def _val_scans(cfg: TrainConfig, out: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    scans = []
    middle = _middle(cfg)
    for seed in cfg.val_seeds:
        ds = _sim(seed, cfg.frames)
        store = _labelled(ds, out / "labels" / f"seed-{seed}")
        for i in np.linspace(middle.start, middle.stop - 1, cfg.val_frames).round().astype(int):
            f = ds[i]
            lab, _ = store.read(i, len(f))
            pick = _sample(cfg.points_in, len(f), np.random.default_rng([cfg.seed, 7, seed, i]))
            scans.append((f.points[pick], features(f)[pick], lab[pick].astype(np.int64)))
    return scans


def train(cfg: TrainConfig, progress: Callable[[str, int, int], None] | None = None) -> Path:
    """Train (or resume) into ``cfg.out``; returns the path of the last checkpoint."""
    import torch

    from lwbench import resolve_device

    if len(_middle(cfg)) < 1:
        raise ParameterError(f"train poconet: margin {cfg.margin} at each end leaves none of {cfg.frames} scans")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    device = resolve_device(cfg.device)
    torch.manual_seed(cfg.seed)
    net_cfg = NetConfig(**{**cfg.net, "d_out": tuple(cfg.net["d_out"])})
    net = PocoNet(net_cfg).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=cfg.decay)
    start_epoch, elapsed = 0, 0.0
    last = out / "last.pt"
    if last.exists():
        state = torch.load(last, map_location=device, weights_only=True)
        net.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        start_epoch, elapsed = int(state["epoch"]), float(state["elapsed_s"])
    (out / "config.json").write_text(json.dumps(asdict(cfg), indent=1))

    stores = []
    for seed in cfg.train_seeds:
        ds = _sim(seed, cfg.frames)
        if progress:
            progress(f"labelling sim seed {seed}", 0, 1)
        stores.append((ds, _labelled(ds, out / "labels" / f"seed-{seed}")))
    weights = torch.as_tensor(_class_weights(stores), dtype=torch.float32, device=device)
    val = _val_scans(cfg, out)
    samples = [(d, s, i) for d, s in stores for i in _middle(cfg)]
    t_start = time.perf_counter() - elapsed
    for epoch in range(start_epoch, cfg.epochs):
        rng = np.random.default_rng([cfg.seed, epoch])
        order = rng.permutation(len(samples))
        losses = []
        for step, k in enumerate(order):
            if cfg.time_budget_s is not None and time.perf_counter() - t_start > cfg.time_budget_s:
                break
            ds, store, i = samples[k]
            f = ds[i]
            lab, _ = store.read(i, len(f))
            pick = _sample(cfg.points_in, len(f), rng)
            pts, feats, lab = f.points[pick], features(f)[pick], lab[pick]
            sel = crop(len(pts), cfg.crop, pts, rng)
            pts, feats, lab = pts[sel], feats[sel], lab[sel]
            if rng.random() < cfg.intensity_dropout:
                feats[:, 3] = 0.0  # a scan without intensity (KITTI's odometry .bin) is the same input
            if cfg.rotate:
                pts = augment_yaw(pts, rng)
                feats[:, :3] = pts
            pair = [to_torch([prepare(pts, net_cfg.k, net_cfg.ratio, len(net_cfg.d_out), rng)], [feats], device)
                    for _ in range(2)]
            (l1, c1), (l2, c2) = net(pair[0]), net(pair[1])
            target = torch.as_tensor(lab.astype(np.int64), device=device).unsqueeze(0)
            loss, parts = siamese_loss((l1, l2), (c1, c2), target, weights, cfg.lam)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(parts)
            if progress:
                progress(f"epoch {epoch + 1}/{cfg.epochs} loss {parts['loss']:.3f}", step + 1, len(order))
        sched.step()
        metrics = evaluate_scans(net, val, net_cfg, device)
        record = {
            "epoch": epoch + 1,
            "steps": len(losses),
            "elapsed_s": time.perf_counter() - t_start,
            "lr": opt.param_groups[0]["lr"],
            **{k: float(np.mean([p[k] for p in losses])) if losses else math.nan for k in ("loss", "label", "global")},
            **metrics,
        }
        with open(out / "curve.jsonl", "a") as fh:
            fh.write(json.dumps(record) + "\n")
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": net_cfg.as_dict(),
            "model": net.state_dict(),
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
