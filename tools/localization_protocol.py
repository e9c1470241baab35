"""Does the localization protocol tell selectors apart? raw vs random at 1/12 and below, 3 seeds.

    python tools/localization_protocol.py [--frames 40] [--seeds 0 1 2] [--param KEY=VALUE ...]

Builds the simulated street with the given sim parameters (default: the PocoNet protocol of
issue 14 -- two drives, noise 2 cm, motion distortion), keeps each frame's points with the
codec, and runs lwbench's localization metric (map from the first drive's decoded scans, the
second drive tracked). Prints Markdown: trans ATE (rmse, mean), rotation error, map share per
codec and seed, and the ratio random/raw.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lwbench import SequenceEvaluation, codec_class, open_dataset, sequence_metric

PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": True}
# Measured with these defaults (frames=30, seeds 0-2): raw 1.36 +- 0.25 cm, random 1/12 2.76 +- 0.96 cm.
CODECS = [("raw", {}), ("random", {"ratio": 1 / 12}), ("random", {"ratio": 1 / 24}), ("random", {"ratio": 1 / 48})]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames per drive")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="a sim parameter")
    ap.add_argument("--icp", action="append", default=[], metavar="KEY=VALUE", help="an ICP setting (float)")
    args = ap.parse_args()
    params = {**PROTOCOL, **dict(kv.split("=", 1) for kv in args.param), "frames": args.frames}
    print(f"sim {params}\n")
    print("| codec | seed | ATE rmse (m) | ATE mean (m) | rot (deg) | ICP failures | map share | s |")
    print("|---|---|---|---|---|---|---|---|")
    results: dict[str, list[float]] = {}
    for seed in args.seeds:
        ds = open_dataset("sim", {**params, "seed": seed})
        idx = list(range(len(ds)))
        frames = [ds[i] for i in idx]
        for name, p in CODECS:
            cls = codec_class(name)
            codec = cls(**({**p, "seed": seed} if "seed" in {q.name for q in cls.all_params()} else p))
            decoded = [codec.decode(codec.encode(f)) for f in frames]
            t = time.time()
            metric = sequence_metric("localization")
            metric.settings = {**metric.settings, **{k: float(v) for k, v in (kv.split("=", 1) for kv in args.icp)}}
            out = metric.compute(SequenceEvaluation(ds, idx, decoded, name, p, seed))
            label = name + (f" 1/{round(1 / p['ratio'])}" if "ratio" in p else "")
            results.setdefault(label, []).append(out["ate_rmse"])
            print(
                f"| {label} | {seed} | {out['ate_rmse']:.4f} | {out['ate_mean']:.4f} | {out['rot_err_deg']:.3f} | "
                f"{out['icp_failures']:.0f} | {out['map_share']:.4f} | {time.time() - t:.0f} |"
            )
    raw = np.array(results["raw"])
    print("\n| codec | ATE rmse mean ± std over seeds | x raw (per seed, mean) |")
    print("|---|---|---|")
    for label, v in results.items():
        v = np.array(v)
        print(f"| {label} | {v.mean():.4f} ± {v.std():.4f} | {np.mean(v / raw):.2f} |")


if __name__ == "__main__":
    main()
