"""Does PocoNet's global module (GFA) do anything? The swap / zero ablation on held-out scans.

    python tools/poconet_ablation.py [--weights shipped] [--seeds 100 101 102 103 104] [--frames 10 40]
        [--labels-root lwbench-results/poconet_labels]

For each listed frame of each seed's two-drive street (labels from ``tools/poconet_table.py``'s
``mapping`` folders), the network's prediction on the trained-density sample with its own
codeword, with the codeword of a scan of *another seed* (another street), and with a zero
codeword (the normalized codeword's mean): the share of points whose predicted class changes,
the mean absolute change of P(high), and the AUC of P(high) against the labels in each case
(:func:`lwbench_plugins.poconet.train.gfa_ablation`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": True, "frames": 30}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--weights", default="shipped")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    ap.add_argument("--frames", type=int, nargs="+", default=[10, 40])
    ap.add_argument("--labels-root", type=Path, default=Path("lwbench-results/poconet_labels"))
    args = ap.parse_args()
    from lwbench_plugins.poconet.codec import SHIPPED_WEIGHTS, load_checkpoint, trained_points_in
    from lwbench_plugins.poconet.data import features
    from lwbench_plugins.poconet.labels import LabelStore
    from lwbench_plugins.poconet.train import gfa_ablation

    from lwbench import open_dataset

    weights = str(SHIPPED_WEIGHTS if args.weights == "shipped" else args.weights)
    net, meta = load_checkpoint(weights, "cpu")
    n_in = trained_points_in(meta)
    scans = []
    for frame_index in args.frames:  # ordered frame-major: the partner half a list away is another seed
        for seed in args.seeds:
            ds = open_dataset("sim", {**PROTOCOL, "seed": seed})
            store = LabelStore(args.labels_root / f"urban-auto-30-seed-{seed}-mapping")
            f = ds[frame_index]
            lab, _ = store.read(frame_index, len(f))
            pick = np.sort(np.random.default_rng([0, seed, frame_index]).choice(len(f), n_in, replace=False))
            scans.append((f.points[pick].astype(np.float32), features(f)[pick], lab[pick].astype(np.int64)))
    out = gfa_ablation(net, scans, "cpu")
    print(f"{weights}: {len(scans)} held-out scans (seeds {args.seeds}, frames {args.frames})\n")
    print("| codeword | predicted classes changed | mean abs. change of P(high) | AUC of P(high) (mapping labels) |")
    print("|---|---|---|---|")
    print(f"| own | – | – | {out['gfa_own_auc']:.4f} |")
    for case, what in (("swap", "another street's"), ("zero", "zero")):
        print(
            f"| {what} | {100 * out[f'gfa_{case}_changed']:.2f} % | {out[f'gfa_{case}_dp']:.4f} | "
            f"{out[f'gfa_{case}_auc']:.4f} |"
        )


if __name__ == "__main__":
    main()
