"""PocoNet's Table I on held-out simulated drives: every selector at one budget, localization.

    python tools/poconet_table.py [--seeds 100 101 102] [--frames 30] [--ratio 0.0833] [--store PATH]

For each held-out seed: the street of the localization protocol (two drives: the map is built
from the first drive's selected points, the second is tracked), labels for the oracle written
with ``lwbench label``, then ``lwbench run`` of raw (the paper's Origin), random, harris3d,
iss, sift3d, poconet and oracle, all keeping the same share of every scan. Prints Markdown:
trans ATE (mean, as the paper's mATE, and rmse), rotation error, mAPE, map points N and map
share r_c, mean ± std over the seeds.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

SELECTORS = ("raw", "random", "harris3d", "iss", "sift3d", "poconet", "oracle")
PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": "true"}


def lwbench(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "lwbench.cli", *args], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"lwbench {' '.join(args)} failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return res.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102])
    ap.add_argument("--frames", type=int, default=30, help="frames per drive")
    ap.add_argument("--ratio", type=float, default=1 / 12)
    ap.add_argument("--store", type=Path, default=Path("lwbench-results/poconet_table.sqlite"))
    ap.add_argument("--work", type=Path, default=Path("lwbench-results/poconet_labels"))
    ap.add_argument("--weights", default="shipped")
    args = ap.parse_args()
    rows: dict[str, list[dict]] = {s: [] for s in SELECTORS}
    for seed in args.seeds:
        ds = ["--dataset", "sim", *(a for k, v in {**PROTOCOL, "frames": args.frames}.items()
                                    for a in ("--dataset-param", f"{k}={v}"))]
        labels = args.work / f"seed-{seed}"
        if not (labels / "labels.json").exists():
            lwbench("label", "sim", "--out", str(labels), *ds[2:], "--dataset-param", f"seed={seed}")
        run = ["run", *ds, "--seed", str(seed), "--store", str(args.store), "--columns", "ate_rmse"]
        for s in SELECTORS:
            run += ["--codec", s]
            if s != "raw":
                run += ["--param", f"{s}.ratio={args.ratio}"]
        run += ["--param", f"oracle.labels={labels}", "--param", f"poconet.weights={args.weights}"]
        lwbench(*run)
        board = json.loads(lwbench("leaderboard", "--store", str(args.store), "--format", "json"))
        for entry in board:
            if entry["codec"] in rows and f"seed={seed}" in entry["dataset"] and (
                entry["codec"] == "raw" or abs(entry["params"].get("ratio", 0) - args.ratio) < 1e-9
            ):
                rows[entry["codec"]].append(entry)
    print(f"\n{len(args.seeds)} held-out seeds {args.seeds}, {args.frames} frames per drive, "
          f"budget {args.ratio:.4f} of every scan (raw keeps all)\n")
    print("| method | trans mATE (m) | trans ATE rmse (m) | rot error (deg) | mAPE | N (map points) | r_c |")
    print("|---|---|---|---|---|---|---|")
    for s in SELECTORS:
        e = rows[s]
        if not e:
            continue

        def stat(key: str, fmt: str) -> str:
            v = np.array([x[key] for x in e if x.get(key) is not None], dtype=float)
            return f"{v.mean():{fmt}} ± {v.std():{fmt}}" if len(v) else "–"

        print(f"| {s} | {stat('ate_mean', '.4f')} | {stat('ate_rmse', '.4f')} | {stat('rot_err_deg', '.4f')} | "
              f"{stat('mape', '.4f')} | {stat('map_points', ',.0f')} | {stat('map_share', '.4f')} |")


if __name__ == "__main__":
    main()
