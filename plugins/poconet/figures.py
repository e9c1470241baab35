"""``lwbench poconet-ablation`` and ``lwbench poconet-real``: two of docs/poconet.md's figures that
look inside the network (registered with PocoNet's other commands through
``lwbench_register_commands``).

    lwbench poconet-ablation [--weights shipped] [--seeds 100,101,102,103,104] [--frames 10,40]
        [--labels-root lwbench-results/poconet_labels]
    lwbench poconet-real SCAN_FOLDER ... [--ratio 1/12] [--weights shipped] [--png DIR]

**Ablation** -- does the global module (GFA) do anything? For each listed frame of each seed's
two-drive street (labels from ``lwbench poconet-table``'s ``mapping`` folders), the network's
prediction on the trained-density sample with its own codeword, with the codeword of a scan of
*another seed* (another street), and with a zero codeword (the normalized codeword's mean): the
share of points whose predicted class changes, the mean absolute change of P(high), and the AUC
of P(high) against the labels in each case (:func:`.train.gfa_ablation`).

**Real scans** -- the selection on real scans the network was not trained on (the paper's Ford
test, on what one has): each folder's first frame through the checkpoint at the budget: whether
exactly the budget is kept, what the network predicts for the whole scan and for the kept points
(high priority / ground / low), and where the kept points are against a random selection of the
same size -- their range, their height above the scan's lowest decile, and the share on the
ground plane RANSAC finds (the labels' own ground rule, :func:`.labels.ground_mask`). ``--png``
writes a top-down picture of each scan with the kept points coloured by predicted class. The
last column is the heading check: mean P(high) on either side of the sensor and within / beyond
8 m sideways.

No ``from __future__ import annotations``: typer reads the annotations at run time.
"""

from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from lwbench import ParameterError

from .table_command import PROTOCOL as TABLE_PROTOCOL
from .table_command import numbers

__all__ = ["describe", "lateral_bias", "register"]

#: The held-out streets of Table I (``lwbench poconet-table``'s protocol, 30 frames a drive).
PROTOCOL = {**TABLE_PROTOCOL, "distortion": True, "frames": 30}


def ablation(weights: str, seeds: list[int], frames: list[int], labels_root: Path) -> None:
    from lwbench import open_dataset

    from .codec import SHIPPED_WEIGHTS, load_checkpoint, trained_points_in
    from .data import features
    from .labels import LabelStore
    from .train import gfa_ablation

    if len(seeds) * len(frames) < 2:
        raise ParameterError("poconet-ablation: the swap needs at least two scans (two seeds or two frames)")
    path = str(SHIPPED_WEIGHTS if weights == "shipped" else weights)
    net, meta = load_checkpoint(path, "cpu")
    n_in = trained_points_in(meta)
    scans = []
    for frame_index in frames:  # ordered frame-major: the partner half a list away is another seed
        for seed in seeds:
            folder = labels_root / f"urban-auto-30-seed-{seed}-mapping"
            if not (folder / "labels.json").exists():
                raise ParameterError(f"--labels-root: no labels at {folder} (lwbench poconet-table --seeds {seed} "
                                     "writes them)")
            ds = open_dataset("sim", {**PROTOCOL, "seed": seed})
            f = ds[frame_index]
            lab, _ = LabelStore(folder).read(frame_index, len(f))
            pick = np.sort(np.random.default_rng([0, seed, frame_index]).choice(len(f), n_in, replace=False))
            scans.append((f.points[pick].astype(np.float32), features(f)[pick], lab[pick].astype(np.int64)))
    out = gfa_ablation(net, scans, "cpu")
    print(f"{path}: {len(scans)} held-out scans (seeds {seeds}, frames {frames})\n")
    print("| codeword | predicted classes changed | mean abs. change of P(high) | AUC of P(high) (mapping labels) |")
    print("|---|---|---|---|")
    print(f"| own | – | – | {out['gfa_own_auc']:.4f} |")
    for case, what in (("swap", "another street's"), ("zero", "zero")):
        print(
            f"| {what} | {100 * out[f'gfa_{case}_changed']:.2f} % | {out[f'gfa_{case}_dp']:.4f} | "
            f"{out[f'gfa_{case}_auc']:.4f} |"
        )


def describe(points: np.ndarray, keep: np.ndarray, ground_mask: np.ndarray) -> dict[str, float]:
    """Range, height and ground share of the kept points."""
    kept = points[keep]
    floor = np.percentile(points[:, 2], 10)
    return {
        "range_m": float(np.median(np.linalg.norm(kept, axis=1))),
        "height_m": float(np.median(kept[:, 2] - floor)),
        "ground": float(ground_mask[keep].mean()),
    }


def lateral_bias(points: np.ndarray, p_high: np.ndarray, cls: np.ndarray) -> tuple[float, float, float, float]:
    """Mean P(high) of the non-ground points left (y > 0) and right of the sensor, and within /
    beyond 8 m sideways: a network that learned where the simulated street's façades lie
    (always on one side, at fixed offsets) shows it here on a real street."""
    rest = cls != 2
    y, p = points[rest, 1], p_high[rest]

    def mean(m: np.ndarray) -> float:
        return float(p[m].mean()) if m.any() else float("nan")

    return mean(y > 0), mean(y < 0), mean(np.abs(y) < 8), mean(np.abs(y) >= 8)


def top_down(path: Path, points: np.ndarray, keep: np.ndarray, cls: np.ndarray, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .labels import CLASSES

    fig, ax = plt.subplots(figsize=(7, 7), dpi=110)
    ax.scatter(points[:, 0], points[:, 1], s=0.05, c="0.8", rasterized=True)
    colours = ("tab:red", "tab:blue", "tab:green")
    for c, name in enumerate(CLASSES):
        k = keep[cls[keep] == c]
        ax.scatter(points[k, 0], points[k, 1], s=0.4, c=colours[c], label=f"{name} ({len(k):,})", rasterized=True)
    lim = float(np.percentile(np.abs(points[:, :2]), 95)) * 1.1
    ax.set(xlim=(-lim, lim), ylim=(-lim, lim), aspect="equal", title=title, xlabel="x (m)", ylabel="y (m)")
    ax.legend(loc="upper right", markerscale=12, fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def real_scans(folders: list[Path], ratio: float, weights: str, png: Path | None) -> None:
    from lwbench import codec_class, open_dataset

    from .codec import PocoNetSelector
    from .labels import CLASSES, LabelSettings, ground_mask

    print(f"budget {ratio:.4f} of every scan; shares: predicted class of the whole scan / of the kept points")
    print(
        "| scan | points | budget | kept | predicted "
        + " / ".join(CLASSES)
        + " (scan) | kept "
        + " / ".join(CLASSES)
        + " | kept: median range, height, on ground | random: same | "
        "mean P(high), non-ground: left / right, abs(y) < 8 m / > 8 m |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for folder in folders:
        frame = open_dataset(folder)[0]
        sel = PocoNetSelector(ratio=ratio, weights=weights)
        probs = sel.probabilities(frame)
        cls = probs.argmax(axis=1)
        keep = sel.select(frame)
        rand = codec_class("random")(ratio=ratio, seed=0).select(frame)
        ground = ground_mask(frame.points, LabelSettings())
        scan_share = np.bincount(cls, minlength=3) / len(frame)
        kept_share = np.bincount(cls[keep], minlength=3) / max(1, len(keep))
        ours, theirs = describe(frame.points, keep, ground), describe(frame.points, rand, ground)

        def fmt(d: dict[str, float]) -> str:
            return f"{d['range_m']:.1f} m, {d['height_m']:.2f} m, {d['ground']:.0%}"

        side = lateral_bias(frame.points, probs[:, 1], cls)
        print(
            f"| {folder.name} | {len(frame):,} | {sel.budget(len(frame)):,} | {len(keep):,} | "
            + " / ".join(f"{s:.1%}" for s in scan_share)
            + " | "
            + " / ".join(f"{s:.1%}" for s in kept_share)
            + f" | {fmt(ours)} | {fmt(theirs)} | "
            + " / ".join(f"{v:.3f}" for v in side)
            + " |",
            flush=True,
        )
        if png is not None:
            png.mkdir(parents=True, exist_ok=True)
            top_down(
                png / f"poconet_{folder.name}.png",
                frame.points,
                keep,
                cls,
                f"poconet on {folder.name} (first frame): {len(keep):,} of {len(frame):,} points",
            )


def register(cli: typer.Typer) -> None:
    """Add ``lwbench poconet-ablation`` and ``lwbench poconet-real``."""

    @cli.command("poconet-ablation")
    def poconet_ablation(
        weights: Annotated[str, typer.Option(help="A checkpoint, or 'shipped'.")] = "shipped",
        seeds: Annotated[str, typer.Option(
            help="Held-out seeds, comma-separated (default: 100,101,102,103,104).", show_default=False)]
        = "100,101,102,103,104",
        frames: Annotated[str, typer.Option(help="Frames of each street, comma-separated.")] = "10,40",
        labels_root: Annotated[Path, typer.Option(
            help="Where lwbench poconet-table wrote its label folders (default: poconet_labels in "
            "lwbench-results/).", show_default=False)] = Path("lwbench-results/poconet_labels"),
    ) -> None:
        """Does PocoNet's global module do anything? Predictions with each scan's own codeword, another
        street's and a zero one: classes changed, change of P(high), AUC; Markdown."""
        ablation(weights, [int(s) for s in numbers(seeds, "--seeds", int)],
                 [int(f) for f in numbers(frames, "--frames", int)], labels_root)

    @cli.command("poconet-real")
    def poconet_real(
        folders: Annotated[list[Path], typer.Argument(
            metavar="SCANS", help="Dataset folders or scan files (their first frame each).")],
        ratio: Annotated[str, typer.Option(help="The budget (1/12 reads as a fraction).")] = "1/12",
        weights: Annotated[str, typer.Option(help="A checkpoint, or 'shipped'.")] = "shipped",
        png: Annotated[Path | None, typer.Option(help="Folder for a top-down picture of each scan.")] = None,
    ) -> None:
        """PocoNet on real scans it was not trained on: predicted classes of the scan and of the kept
        points, where the kept points lie against random's, the heading check; Markdown."""
        budget = numbers(ratio, "--ratio")
        if len(budget) != 1 or not 0 < budget[0] <= 1:
            raise ParameterError(f"--ratio {ratio!r}: one share of the scan, in (0, 1]")
        real_scans(list(folders), budget[0], weights, png)
