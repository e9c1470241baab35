"""PocoNet's learning curve: loss and held-out per-class accuracy / IoU per epoch, and the
held-out localization ATE of a few checkpoints.

    python tools/poconet_curve.py RUN_DIR [--ate-epochs 1 3 5] [--seed 100] [--png docs/poconet_curve.png]

``RUN_DIR`` is a ``lwbench train poconet --out`` folder (``curve.jsonl``, ``epoch-NNN.pt``). The
ATE column runs the localization protocol (``tools/poconet_table.py``'s street, one held-out
seed, budget 1/12) with that epoch's checkpoint.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path


def held_out_ate(checkpoint: Path, seed: int, frames: int, store: Path) -> float:
    """ATE rmse (m) of poconet with ``checkpoint`` on the held-out street."""
    tool = Path(__file__).with_name("poconet_table.py")
    res = subprocess.run(
        [sys.executable, str(tool), "--seeds", str(seed), "--frames", str(frames), "--selectors", "poconet",
         "--weights", str(checkpoint), "--store", str(store)],
        capture_output=True, text=True, check=True,
    )
    row = next(line for line in res.stdout.splitlines() if line.startswith("| poconet"))
    return float(row.split("|")[3].split("±")[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--ate-epochs", type=int, nargs="*", default=[])
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--png", type=Path)
    args = ap.parse_args()
    curve = [json.loads(line) for line in (args.run / "curve.jsonl").read_text().splitlines() if line.strip()]
    ate = {}
    for epoch in args.ate_epochs:
        ckpt = args.run / f"epoch-{epoch:03d}.pt"
        ate[epoch] = held_out_ate(ckpt, args.seed, args.frames, args.run / f"ate-epoch-{epoch:03d}.sqlite")
    print("| epoch | steps | minutes | loss | acc high / low / ground | IoU high / low / ground | mIoU | "
          f"held-out ATE rmse (seed {args.seed}, 1/12) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in curve:
        acc = " / ".join(f"{r[f'acc_{c}']:.2f}" for c in ("high_priority", "low_priority", "ground"))
        iou = " / ".join(f"{r[f'iou_{c}']:.2f}" for c in ("high_priority", "low_priority", "ground"))
        a = f"{100 * ate[r['epoch']]:.2f} cm" if r["epoch"] in ate else ""
        print(f"| {r['epoch']} | {r['steps']} | {r['elapsed_s'] / 60:.1f} | {r['loss']:.3f} | {acc} | {iou} | "
              f"{r['miou']:.3f} | {a} |")
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        epochs = [r["epoch"] for r in curve]
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.6), dpi=110)
        ax1.plot(epochs, [r["loss"] for r in curve], "o-", label="training loss")
        ax1.set(xlabel="epoch", ylabel="loss", title="training loss (siamese, class-weighted)")
        for c, style in (("high_priority", "o-"), ("low_priority", "s-"), ("ground", "^-")):
            ax2.plot(epochs, [r[f"iou_{c}"] for r in curve], style, label=f"IoU {c.replace('_', ' ')}")
        ax2.plot(epochs, [r["acc_high_priority"] for r in curve], "o--", label="accuracy high priority")
        ax2.set(xlabel="epoch", ylim=(0, 1), title="validation scans (drive 20, never trained on)")
        ax2.legend(fontsize=8)
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.png)


if __name__ == "__main__":
    main()
