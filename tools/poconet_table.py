"""PocoNet's Table I on held-out simulated drives: every selector at one budget, localization.

    python tools/poconet_table.py [--seeds 100 101 102] [--frames 30] [--ratio 0.0833] [--store PATH]
    python tools/poconet_table.py --scene indoor --seeds 100     # generalization: another scene
    python tools/poconet_table.py --sensor os1-128 --seeds 100   # ... or another sensor

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
COLUMNS = (("ate_mean", ".4f"), ("ate_rmse", ".4f"), ("rot_err_deg", ".4f"), ("mape", ".4f"),
           ("map_points", ",.0f"), ("map_share", ".4f"))
PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": "true"}


def lwbench(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "lwbench.cli", *args], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"lwbench {' '.join(args)} failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return res.stdout


def stat(entries: list[dict], key: str, fmt: str) -> str:
    """``mean ± std`` of one column over the seeds' entries."""
    v = np.array([x[key] for x in entries if x.get(key) is not None], dtype=float)
    return f"{v.mean():{fmt}} ± {v.std():{fmt}}" if len(v) else "–"


def same_protocol(entry: dict, protocol: dict) -> bool:
    """Whether a leaderboard entry's dataset label is this protocol's street (scene, sensor)."""
    label = entry["dataset"]
    return f"scene={protocol['scene']}" in label and (
        protocol["sensor"] == "auto" or f"sensor={protocol['sensor']}" in label
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102])
    ap.add_argument("--frames", type=int, default=30, help="frames per drive")
    ap.add_argument("--ratio", type=float, default=1 / 12)
    ap.add_argument("--store", type=Path, default=Path("lwbench-results/poconet_table.sqlite"))
    ap.add_argument("--work", type=Path, default=Path("lwbench-results/poconet_labels"))
    ap.add_argument("--weights", default="shipped")
    ap.add_argument("--scene", default=PROTOCOL["scene"])
    ap.add_argument("--sensor", default="auto")
    ap.add_argument("--selectors", nargs="+", default=list(SELECTORS), choices=SELECTORS)
    ap.add_argument("--param", action="append", default=[], help="CODEC.KEY=VALUE passed to lwbench run")
    args = ap.parse_args()
    selectors = [s for s in SELECTORS if s in args.selectors]
    rows: dict[str, list[dict]] = {s: [] for s in selectors}
    protocol = {**PROTOCOL, "scene": args.scene, "sensor": args.sensor, "frames": args.frames}
    for seed in args.seeds:
        ds = ["--dataset", "sim", *(a for k, v in protocol.items() for a in ("--dataset-param", f"{k}={v}"))]
        labels = args.work / f"{args.scene}-{args.sensor}-{args.frames}-seed-{seed}"
        if "oracle" in selectors and not (labels / "labels.json").exists():
            lwbench("label", "sim", "--out", str(labels), *ds[2:], "--dataset-param", f"seed={seed}")
        run = ["run", *ds, "--seed", str(seed), "--store", str(args.store), "--columns", "ate_rmse"]
        for s in selectors:
            run += ["--codec", s]
            if s != "raw":
                run += ["--param", f"{s}.ratio={args.ratio}"]
        if "oracle" in selectors:
            run += ["--param", f"oracle.labels={labels}"]
        if "poconet" in selectors:
            run += ["--param", f"poconet.weights={args.weights}"]
        for extra in args.param:
            run += ["--param", extra]
        lwbench(*run)
        board = json.loads(lwbench("leaderboard", "--store", str(args.store), "--format", "json"))
        for entry in board:
            if entry["codec"] in rows and f"seed={seed}" in entry["dataset"] and same_protocol(entry, protocol) and (
                entry["codec"] == "raw" or abs(entry["params"].get("ratio", 0) - args.ratio) < 1e-9
            ):
                rows[entry["codec"]].append(entry)
    print(f"\nsim {args.scene}, sensor {args.sensor}: {len(args.seeds)} held-out seeds {args.seeds}, "
          f"{args.frames} frames per drive, "
          f"budget {args.ratio:.4f} of every scan (raw keeps all)\n")
    print("| method | trans mATE (m) | trans ATE rmse (m) | rot error (deg) | mAPE | N (map points) | r_c |")
    print("|---|---|---|---|---|---|---|")
    for s in selectors:
        e = rows[s]
        if not e:
            continue
        cells = [stat(e, key, fmt) for key, fmt in COLUMNS]
        print(f"| {s} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
