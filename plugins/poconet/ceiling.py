"""``lwbench poconet-ceiling``: how predictable are PocoNet's labels from one scan at all?

PocoNet's labels say which points a *sequence* observes often (observation counts over the
mapping drive); the network must guess them from *one* scan. Before blaming the network for a
held-out AUC of 0.63, this asks what hand-made per-point features of the scan -- no sequence,
no learning of geometry -- can do with the same labels: a gradient-boosted tree model
(scikit-learn's HistGradientBoostingClassifier) fitted on the training streets' labels and
scored on held-out streets, beside the shipped network's P(high) on the *same* points, and
each feature alone.

Features per point (from the scan, in the sensor frame): range; height (z); the local
structure of its 16 nearest neighbours -- linearity, planarity, scattering (from the
covariance's eigenvalues), verticality (1 - |n_z| of the smallest eigenvector), the neighbours'
spread in height; density (the 16th neighbour's distance over the range, what the beam pattern
alone would give); and intensity when the scan has it.

    lwbench poconet-ceiling [--train urban:30-37] [--test urban:100-104] [--out DIR]
        [--weights CHECKPOINT] [--write-scores DIR]

``--write-scores DIR`` also writes the model's scores of every point of each held-out drive, so
``lwbench poconet-table --scores DIR`` can rank by them under PocoNet's own selection rule.

Requires scikit-learn (``pip install scikit-learn``; in ``lwbench[dev]``). No ``from __future__
import annotations``: typer reads the annotations at run time.
"""

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from lwbench import Frame, MissingDependencyError, ParameterError

from .diagnostics import GROUND, HIGH, roc_auc, top_k_precision
from .labels import LabelSettings

FEATURES = ("range", "height", "linearity", "planarity", "scattering", "verticality", "height_spread",
            "density", "intensity")
NEIGHBOURS = 16


def point_features(frame: Frame, rows: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
    """``(len(rows), len(FEATURES))`` float64: the features of the points ``rows`` of ``frame``,
    their neighbourhoods taken in the whole scan, or only among the points ``among`` (a sample
    of the scan: what a network that sees a sample can know)."""
    from scipy.spatial import cKDTree

    pts = np.asarray(frame.points, dtype=np.float64)
    q = pts[rows]
    dist, idx = cKDTree(pts if among is None else pts[among]).query(q, k=NEIGHBOURS)
    if among is not None:
        idx = np.asarray(among)[idx]
    nb = pts[idx]  # (n, k, 3)
    centred = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", centred, centred) / NEIGHBOURS
    w, v = np.linalg.eigh(cov)  # ascending
    l1, l2, l3 = w[:, 2], w[:, 1], w[:, 0]
    s = np.maximum(l1, 1e-12)
    rng = np.linalg.norm(q, axis=1)
    inten = frame.intensity
    intensity = (np.asarray(inten, np.float64)[rows] if inten is not None and len(inten) == len(pts)
                 else np.zeros(len(rows)))
    return np.column_stack([
        rng, q[:, 2], (l1 - l2) / s, (l2 - l3) / s, l3 / s, 1.0 - np.abs(v[:, 2, 0]), nb[:, :, 2].std(axis=1),
        dist[:, -1] / np.maximum(rng, 1e-6), intensity,
    ])


def _drive_samples(drive: str, out: Path, frames: int, scans: int, points: int, seed: int, network=None,
                   context: int | None = None):
    """Features, labels (high = 1 among non-ground points) and, with ``network``, its P(high),
    of ``scans`` evenly spaced scans of each day of ``drive`` (``points`` sampled per scan).
    With ``context``, each scan is first sampled to that many points (as the network's input
    is), the points and their neighbourhoods drawn from the sample."""
    from .train import _labelled, _sim

    ds = _sim(drive, frames)
    store = _labelled(ds, out / "labels" / drive.replace(":", "-"), LabelSettings(counts_from="mapping"))
    feats, labels, scores = [], [], []
    for day, traversal in enumerate(ds.traversals()):
        for i in np.linspace(0, len(traversal) - 1, scans).round().astype(int):
            frame = ds[traversal[i]]
            lab, _ = store.read(frame.index, len(frame))
            rng = np.random.default_rng([seed, day, int(i)])
            among = None
            if context is not None and context < len(frame):
                among = np.sort(np.random.default_rng([seed, 9, day, int(i)]).choice(len(frame), context,
                                                                                      replace=False))
            rest = np.flatnonzero(lab != GROUND) if among is None else among[lab[among] != GROUND]
            rows = np.sort(rng.choice(rest, min(points, len(rest)), replace=False))
            feats.append(point_features(frame, rows, among))
            labels.append((lab[rows] == HIGH).astype(np.int8))
            if network is not None:
                scores.append(network.scores(frame)[rows])
    return np.concatenate(feats), np.concatenate(labels), (np.concatenate(scores) if scores else None)


def write_scores(model, drive: str, frames: int, folder: Path) -> Path:
    """The features' model's P(high) for every point of every scan of ``drive``, in the layout
    ``poconet score=file`` reads (:class:`.diagnostics.ScoreFolder`): so a selector can rank by
    the ceiling's scores under PocoNet's own rule, and the localization table can say whether
    scores this good would beat the rule with random scores."""
    from .diagnostics import write_score_folder
    from .train import _sim

    ds = _sim(drive, frames)
    scores = {}
    for i in range(len(ds)):
        frame = ds[i]
        rows = np.arange(len(frame))
        scores[frame.index] = (model.predict_proba(point_features(frame, rows))[:, 1] if len(rows)
                               else np.empty(0))
    return write_score_folder(folder, ds, scores, f"lwbench poconet-ceiling features' model ({', '.join(FEATURES)})")


def ceiling(train: list[str], test: list[str], out: Path, frames: int = 30, scans: int = 6, points: int = 8000,
            seed: int = 0, network=None, say=print, scores_to: Path | None = None,
            context: int | None = None) -> dict:
    """Fit on ``train`` drives, score on each ``test`` drive: AUC and top-k precision of the
    features' model, of the network (if given) and of each feature alone. With ``scores_to``,
    also write the model's scores of every point of each test drive to ``scores_to/SCENE-SEED``
    (:func:`write_scores`)."""
    try:
        from sklearn.ensemble import HistGradientBoostingClassifier
    except ImportError:
        raise MissingDependencyError("poconet-ceiling needs scikit-learn: pip install scikit-learn") from None
    if scores_to is not None and context is not None:
        raise ParameterError("poconet-ceiling: --write-scores takes the whole scan's features; leave out --context")
    xs, ys = [], []
    for drive in train:
        x, y, _ = _drive_samples(drive, out, frames, scans, points, seed, context=context)
        xs.append(x)
        ys.append(y)
        say(f"train {drive}: {len(y)} points, base rate {y.mean():.3f}")
    x, y = np.concatenate(xs), np.concatenate(ys)
    model = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.1, max_leaf_nodes=31,
                                           early_stopping=True, random_state=seed).fit(x, y)
    result = {"train": train, "features": list(FEATURES), "context": context, "train_points": int(len(y)),
              "train_auc": roc_auc(model.predict_proba(x)[:, 1], y.astype(bool)), "test": {}}
    for drive in test:
        xt, yt, st = _drive_samples(drive, out, frames, scans, points, seed, network, context)
        pos = yt.astype(bool)
        n_top = int(pos.sum())
        p = model.predict_proba(xt)[:, 1]
        row = {"points": int(len(yt)), "base_rate": float(pos.mean()), "model_auc": roc_auc(p, pos),
               "model_top_k": top_k_precision(p, pos, n_top),
               "single": {f: max(roc_auc(xt[:, j], pos), 1 - roc_auc(xt[:, j], pos)) for j, f in enumerate(FEATURES)
                          if np.ptp(xt[:, j]) > 0}}
        if st is not None:
            row["network_auc"] = roc_auc(st, pos)
            row["network_top_k"] = top_k_precision(st, pos, n_top)
        result["test"][drive] = row
        if scores_to is not None:
            where = write_scores(model, drive, frames, scores_to / drive.replace(":", "-"))
            say(f"wrote the model's scores of {drive} to {where}")
        say(f"test {drive}: model AUC {row['model_auc']:.3f}" + (
            f", network {row['network_auc']:.3f}" if st is not None else ""))
    return result


def _markdown(result: dict) -> str:
    lines = ["| held-out drive | points | base rate | features' model: AUC / top-k | network: AUC / top-k | "
             "best single feature (AUC) |", "|---|---|---|---|---|---|"]
    for drive, r in result["test"].items():
        best = max(r["single"].items(), key=lambda kv: kv[1])
        net = (f"{r['network_auc']:.3f} / {r['network_top_k']:.3f}" if "network_auc" in r else "–")
        lines.append(f"| {drive} | {r['points']:,} | {r['base_rate']:.3f} | {r['model_auc']:.3f} / "
                     f"{r['model_top_k']:.3f} | {net} | {best[0]} ({best[1]:.3f}) |")
    aucs = [r["model_auc"] for r in result["test"].values()]
    lines.append("")
    if result.get("context"):
        lines.append(f"features taken within a random sample of {result['context']:,} points of each scan")
    lines.append(f"features' model: train AUC {result['train_auc']:.3f} on {result['train_points']:,} points of "
                 f"{len(result['train'])} drives; held-out mean AUC {np.mean(aucs):.3f}")
    nets = [r["network_auc"] for r in result["test"].values() if "network_auc" in r]
    if nets:
        lines.append(f"network ({result.get('weights', 'shipped')} weights): held-out mean AUC {np.mean(nets):.3f}")
    return "\n".join(lines)


def register(cli: typer.Typer) -> None:
    """Add ``lwbench poconet-ceiling``."""

    @cli.command("poconet-ceiling")
    def poconet_ceiling(
        train: Annotated[str, typer.Option(help="Training drives, SCENE:SEED or SCENE:FIRST-LAST, comma-separated.")]
        = "urban:30-37",
        test: Annotated[str, typer.Option(help="Held-out drives (never trained on).")] = "urban:100-104",
        frames: Annotated[int, typer.Option(help="Scans per day of each drive.", min=4)] = 30,
        scans: Annotated[int, typer.Option(help="Scans sampled per day.", min=1)] = 6,
        points: Annotated[int, typer.Option(help="Non-ground points sampled per scan.", min=100)] = 8000,
        network: Annotated[bool, typer.Option(help="Also score the network on the same points.")] = True,
        weights: Annotated[str, typer.Option(help="The network's weights: 'shipped' or a checkpoint.")] = "shipped",
        write_scores_to: Annotated[Path | None, typer.Option(
            "--write-scores", help="Also write the model's scores of every point of each held-out drive to "
            "DIR/SCENE-SEED (read by poconet score=file).")] = None,
        out: Annotated[Path, typer.Option(help="Folder for the labels (reused when they match).")]
        = Path("poconet-ceiling"),
        seed: Annotated[int, typer.Option(help="Seed of the sampling and the model.")] = 0,
        context: Annotated[int | None, typer.Option(
            help="Take each scan's features within a random sample of this many points (the network sees "
            "16,384), not the whole scan.", min=NEIGHBOURS + 1)] = None,
        json_out: Annotated[Path | None, typer.Option("--json", help="Also write the result here.")] = None,
    ) -> None:
        """How predictable PocoNet's labels are from one scan: a tree model on hand-made per-point
        features, fitted on training streets, against the network on held-out streets."""
        import json

        from lwbench import make_codec

        from .train import parse_drives

        net = make_codec("poconet", {"weights": weights}) if network else None
        result = ceiling(list(parse_drives(train)), list(parse_drives(test)), out, frames, scans, points, seed, net,
                         say=lambda line: typer.echo(line, err=True), scores_to=write_scores_to, context=context)
        if network:
            result["weights"] = weights
        print(_markdown(result))
        if json_out is not None:
            json_out.write_text(json.dumps(result, indent=1, default=float))
