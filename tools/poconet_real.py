"""PocoNet's selection on real scans it was not trained on (the paper's Ford test, on what is here).

    python tools/poconet_real.py [FOLDER ...] [--ratio 0.0833] [--weights shipped] [--png DIR]

For each folder (default: the KITTI and Ouster samples in ``shared/data/real``), its first frame
through the shipped checkpoint at the budget: whether exactly the budget is kept, what the
network predicts for the whole scan and for the kept points (high priority / ground / low), and
where the kept points are against a random selection of the same size -- their range, their
height above the scan's lowest decile, and the share on the ground plane RANSAC finds (the
labels' own ground rule, :func:`ground_mask`). ``--png`` writes a top-down picture of each scan
with the kept points coloured by predicted class. The last column is the heading check: mean
P(high) on either side of the sensor and within / beyond 8 m sideways.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _real import real_data_dir  # noqa: E402

from lwbench import codec_class, open_dataset  # noqa: E402

DEFAULT_FOLDERS = ("kitti00_frames0-1", "ouster_os1-128_seq3")


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
    from lwbench_plugins.poconet.labels import CLASSES

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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", type=Path)
    ap.add_argument("--ratio", type=float, default=1 / 12)
    ap.add_argument("--weights", default="shipped")
    ap.add_argument("--png", type=Path)
    args = ap.parse_args()
    from lwbench_plugins.poconet.labels import CLASSES, LabelSettings, ground_mask

    folders = args.folders or [real_data_dir() / f for f in DEFAULT_FOLDERS]
    print(f"budget {args.ratio:.4f} of every scan; shares: predicted class of the whole scan / of the kept points")
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
        sel = codec_class("poconet")(ratio=args.ratio, weights=args.weights)
        probs = sel.probabilities(frame)
        cls = probs.argmax(axis=1)
        keep = sel.select(frame)
        rand = codec_class("random")(ratio=args.ratio, seed=0).select(frame)
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
            + " |"
        )
        if args.png:
            args.png.mkdir(parents=True, exist_ok=True)
            top_down(
                args.png / f"poconet_{folder.name}.png",
                frame.points,
                keep,
                cls,
                f"poconet on {folder.name} (first frame): {len(keep):,} of {len(frame):,} points",
            )


if __name__ == "__main__":
    main()
