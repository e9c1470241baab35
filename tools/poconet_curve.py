"""PocoNet's learning curve: losses, the validation scans' AUC and precision of P(high), IoU,
the global module's swap / zero ablation per epoch, and the validation drive's ATE of a few
checkpoints.

    python tools/poconet_curve.py RUN_DIR [--ate-epochs 1 4] [--seed 20] [--png docs/poconet_curve.png]

``RUN_DIR`` is a ``lwbench train poconet --out`` folder (``curve.jsonl``, ``epoch-NNN.pt``). The
ATE column runs the localization protocol on the *validation* seed (20 by default; never a
Table I seed) at 1/12 with that epoch's checkpoint, next to random on the same drive.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

PROTOCOL = ("scene=urban", "traversals=2", "noise=0.02", "distortion=true", "frames=30")


def validation_ate(checkpoint: Path, seed: int) -> tuple[float, float]:
    """ATE rmse (m) of poconet with ``checkpoint`` and of random, on the validation street."""
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp) / "r.sqlite"
        ds = [a for p in (*PROTOCOL, f"seed={seed}") for a in ("--dataset-param", p)]
        subprocess.run(
            [
                sys.executable,
                "-m",
                "lwbench.cli",
                "run",
                "--dataset",
                "sim",
                *ds,
                "--seed",
                str(seed),
                "--store",
                str(store),
                "--codec",
                "poconet",
                "--param",
                "poconet.ratio=0.0833",
                "--param",
                f"poconet.weights={checkpoint}",
                "--codec",
                "random",
                "--param",
                "random.ratio=0.0833",
            ],
            capture_output=True,
            text=True,
            check=True,
        )
        res = subprocess.run(
            [sys.executable, "-m", "lwbench.cli", "leaderboard", "--store", str(store), "--format", "json"],
            capture_output=True,
            text=True,
            check=True,
        )
    board = {e["codec"]: e["ate_rmse"] for e in json.loads(res.stdout)}
    return board["poconet"], board["random"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--ate-epochs", type=int, nargs="*", default=[])
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--png", type=Path)
    args = ap.parse_args()
    curve = [json.loads(line) for line in (args.run / "curve.jsonl").read_text().splitlines() if line.strip()]
    ate = {e: validation_ate(args.run / f"epoch-{e:03d}.pt", args.seed) for e in args.ate_epochs}
    print(
        "| epoch | steps | minutes | loss (label / global) | AUC P(high) | top-k precision | IoU high / low / ground "
        f"| GFA swap / zero: classes changed, mean abs. change of P(high) | ATE rmse seed {args.seed}, 1/12 "
        "(poconet / random) |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for r in curve:
        iou = " / ".join(f"{r[f'iou_{c}']:.2f}" for c in ("high_priority", "low_priority", "ground"))
        gfa = (
            (
                f"{100 * r['gfa_swap_changed']:.2f} % / {100 * r['gfa_zero_changed']:.2f} %, "
                f"{r['gfa_swap_dp']:.4f} / {r['gfa_zero_dp']:.4f}"
            )
            if "gfa_swap_changed" in r
            else "–"
        )
        a = f"{100 * ate[r['epoch']][0]:.2f} / {100 * ate[r['epoch']][1]:.2f} cm" if r["epoch"] in ate else ""
        auc, top = r.get("auc_high", float("nan")), r.get("top_k_precision", float("nan"))
        print(
            f"| {r['epoch']} | {r['steps']} | {r['elapsed_s'] / 60:.1f} | {r['loss']:.4f} ({r['label']:.4f} / "
            f"{r['global']:.2g}) | {auc:.3f} | {top:.3f} | {iou} | {gfa} | {a} |"
        )
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        epochs = [r["epoch"] for r in curve]
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6), dpi=110)
        ax1.plot(epochs, [r["loss"] for r in curve], "o-", label="training loss")
        ax1.set(xlabel="epoch", ylabel="loss", title="training loss (binary CE + siamese L2)")
        ax2.plot(epochs, [r["auc_high"] for r in curve], "o-", label="AUC of P(high)")
        ax2.plot(epochs, [r["top_k_precision"] for r in curve], "s-", label="top-k precision of P(high)")
        ax2.plot(epochs, [r["iou_ground"] for r in curve], "^-", label="IoU ground")
        ax2.set(xlabel="epoch", ylim=(0, 1), title="validation scans (drive 20, never trained on)")
        ax2.legend(fontsize=8)
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.png)


if __name__ == "__main__":
    main()
