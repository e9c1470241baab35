"""PocoNet's Table I on held-out simulated drives, with per-seed paired differences to random.

    python tools/poconet_table.py [--seeds 100 101 102 103 104] [--frames 30] [--ratios 0.0833 0.0417]
        [--curve-ratios 0.0833] [--json OUT] [--store PATH]
    python tools/poconet_table.py --seeds 101 --no-curve --no-controls --no-diagnose  # headline rows only
    python tools/poconet_table.py --seeds 100 101 --from-store  # one table of seeds run apart
    python tools/poconet_table.py --scene indoor --seeds 100 --no-curve     # another scene
    python tools/poconet_table.py --sensor os1-128 --seeds 100 --no-curve   # ... or another sensor

For each held-out seed: the street of the localization protocol (two drives: the map is built
from the first drive's selected points, the second is tracked); labels of both definitions with
``lwbench label`` (``mapping``: counts from the mapping drive only, what a robot has; ``all``:
counts from both drives, non-causal for the tracked one); then ``lwbench run`` at each budget of

- raw (the paper's Origin), random, harris3d, iss, sift3d, poconet;
- poconet's two controls: ``score=random`` (the same ground quota and spatial balance, random
  order instead of P(high)) and ``cell=0`` (P(high) without spatial balance);
- the oracle on each label definition, and -- at the ``--curve-ratios`` -- the noisy oracle on the
  ``mapping`` labels at ``--precisions`` with the oracle's rule (``class``) and with poconet's rule
  (``score``);

and ``lwbench diagnose poconet`` for the network's AUC and precision against both definitions.
Prints Markdown: per method the translation ATE rmse of every seed, mean ± std, the per-seed
difference to random and on how many seeds it beats random; rotation error, map points, r_c.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": "true"}
MAIN = ("raw", "random", "harris3d", "iss", "sift3d", "poconet")


def lwbench(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "lwbench.cli", *args], capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"lwbench {' '.join(args)} failed:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return res.stdout


def row_name(entry: dict, labels: dict[str, str]) -> str:
    """The table's name of a leaderboard entry (the oracle by its label definition)."""
    p, codec = entry["params"], entry["codec"]
    if codec == "poconet":
        if p.get("score") == "random":
            return "poconet, score=random (control)"
        return "poconet, cell=0 (no balance)" if p.get("cell") == 0 else "poconet"
    if codec == "oracle":
        which = next((k for k, v in labels.items() if Path(p["labels"]) == Path(v)), "?")
        rule = "" if p.get("rule", "class") == "class" else f", rule {p['rule']}"
        prec = "" if p.get("precision") is None else f", noisy p={p['precision']:g}"
        return f"oracle ({which}{rule}{prec})"
    return codec


def one_seed(args, seed: int, ratio: float, curve: bool) -> list[dict]:
    protocol = {**PROTOCOL, "scene": args.scene, "sensor": args.sensor, "frames": args.frames, "seed": seed}
    ds = [a for k, v in protocol.items() for a in ("--dataset-param", f"{k}={v}")]
    tag = f"{args.scene}-{args.sensor}-{args.frames}-seed-{seed}"
    labels = {d: str(args.work / f"{tag}-{d}") for d in ("mapping", "all")}
    for d, folder in labels.items():
        if not args.from_store and not (Path(folder) / "labels.json").exists():
            lwbench("label", "sim", "--out", folder, *ds, "--counts-from", d)
    common = ["run", "--dataset", "sim", *ds, "--seed", str(seed), "--store", str(args.store), "--columns", "ate_rmse"]
    main = [*common]
    for s in MAIN:
        main += ["--codec", s] + ([] if s == "raw" else ["--param", f"{s}.ratio={ratio}"])
    main += ["--param", f"poconet.weights={args.weights}"]
    if args.controls:
        main += ["--param", "poconet.score=p_high,random"]
    main += [
        "--codec",
        "oracle",
        "--param",
        f"oracle.ratio={ratio}",
        "--param",
        f"oracle.labels={labels['mapping']},{labels['all']}",
    ]
    if not args.from_store:
        lwbench(*main)
    if args.controls and not args.from_store:
        lwbench(
            *common,
            "--codec",
            "poconet",
            "--param",
            f"poconet.ratio={ratio}",
            "--param",
            f"poconet.weights={args.weights}",
            "--param",
            "poconet.cell=0",
        )
    if curve and not args.from_store:
        ps = ",".join(f"{p:g}" for p in args.precisions)
        for rule, precisions in (("class", ps), ("score", f"{ps},1")):  # the oracle's rule, poconet's
            lwbench(
                *common,
                "--codec",
                "oracle",
                "--param",
                f"oracle.ratio={ratio}",
                "--param",
                f"oracle.labels={labels['mapping']}",
                "--param",
                f"oracle.precision={precisions}",
                "--param",
                f"oracle.rule={rule}",
            )
    board = json.loads(lwbench("leaderboard", "--store", str(args.store), "--format", "json"))
    rows = []
    for e in board:
        if f"seed={seed}" not in e["dataset"] or f"scene={args.scene}" not in e["dataset"]:
            continue
        if args.sensor != "auto" and f"sensor={args.sensor}" not in e["dataset"]:
            continue
        if e["codec"] != "raw" and abs((e["params"].get("ratio") or 0) - ratio) > 1e-9:
            continue
        if e["codec"] == "poconet" and e["params"].get("weights") != args.weights:
            continue
        rows.append({**e, "row": row_name(e, labels), "seed": seed})
    if args.diagnose:
        out = args.work / f"{tag}-diagnose-{ratio:.4f}.json"
        if not out.exists() and not args.from_store:
            lwbench(
                "diagnose",
                "poconet",
                "--param",
                f"ratio={ratio}",
                "--param",
                f"weights={args.weights}",
                "--dataset",
                "sim",
                *ds,
                "--seed",
                str(seed),
                "--labels",
                f"mapping={labels['mapping']}",
                "--labels",
                f"all={labels['all']}",
                "--json",
                str(out),
            )
        if out.exists():
            rows.append({"row": "poconet diagnostics", "seed": seed, **json.loads(out.read_text())["labels"]})
    return rows


def _cm(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.2f}"


def table(rows: list[dict], seeds: list[int]) -> str:
    """Markdown: per method the ATE rmse per seed, mean ± std, the paired difference to random."""
    ate = {}
    for r in rows:
        if "ate_rmse" in r:
            ate.setdefault(r["row"], {})[r["seed"]] = r
    order = [
        "raw",
        "random",
        "harris3d",
        "iss",
        "sift3d",
        "poconet",
        "poconet, score=random (control)",
        "poconet, cell=0 (no balance)",
        "oracle (mapping)",
        "oracle (all)",
    ]
    ate = dict(sorted(ate.items(), key=lambda kv: (order.index(kv[0]) if kv[0] in order else len(order), kv[0])))
    rnd = ate.get("random", {})
    head = " / ".join(str(s) for s in seeds)
    lines = [
        f"| method | ATE rmse (cm), seeds {head} | mean ± std | − random, per seed (cm) | beats random | "
        "rot error (deg) | N (map points) | r_c |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, per in ate.items():
        vals = [per[s]["ate_rmse"] if s in per else None for s in seeds]
        have = np.array([v for v in vals if v is not None], dtype=float)
        diffs = [
            None if v is None or s not in rnd else v - rnd[s]["ate_rmse"] for v, s in zip(vals, seeds, strict=True)
        ]
        wins = sum(d is not None and d < 0 for d in diffs)
        rot = np.mean([per[s]["rot_err_deg"] for s in per if per[s].get("rot_err_deg") is not None])
        mp = np.mean([per[s]["map_points"] for s in per if per[s].get("map_points") is not None])
        share = np.mean([per[s]["map_share"] for s in per if per[s].get("map_share") is not None])
        lines.append(
            f"| {name} | {' / '.join(_cm(v) for v in vals)} | {100 * have.mean():.2f} ± {100 * have.std():.2f} | "
            + ("–" if name == "random" else " / ".join("–" if d is None else f"{100 * d:+.2f}" for d in diffs))
            + f" | {'–' if name == 'random' else f'{wins}/{len(have)}'} | {rot:.4f} | {mp:,.0f} | {share:.4f} |"
        )
    means = {n: np.mean([r["ate_rmse"] for r in per.values()]) for n, per in ate.items()}
    stds = {n: np.std([r["ate_rmse"] for r in per.values()]) for n, per in ate.items()}
    keypoints = [n for n in ("harris3d", "iss", "sift3d") if n in means]
    if keypoints and "poconet" in means:
        best = min(keypoints, key=means.get)
        inside = abs(means["poconet"] - means[best]) <= stds[best]
        lines += [
            "",
            f"Best keypoint selector: {best} ({100 * means[best]:.2f} ± {100 * stds[best]:.2f} cm); poconet "
            f"({100 * means['poconet']:.2f} cm) is {'within' if inside else 'outside'} its spread.",
        ]
    diag = [r for r in rows if r["row"] == "poconet diagnostics"]
    if diag:
        lines += [
            "",
            "| poconet vs labels | base rate | AUC | top-k precision | kept precision | kept ground share |",
            "|---|---|---|---|---|---|",
        ]
        for d in ("mapping", "all"):
            cols = ("base_rate", "auc", "top_k_precision", "kept_precision", "kept_ground_share")
            cells = [np.mean([r[d][c] for r in diag]) for c in cols]
            lines.append(f"| {d} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103, 104])
    ap.add_argument("--frames", type=int, default=30, help="frames per drive")
    ap.add_argument("--ratios", type=float, nargs="+", default=[1 / 12, 1 / 24])
    ap.add_argument("--curve-ratios", type=float, nargs="*", default=[1 / 12])
    ap.add_argument("--no-curve", action="store_true")
    ap.add_argument(
        "--no-controls",
        dest="controls",
        action="store_false",
        help="skip poconet's two controls (score=random, cell=0): about a quarter of a seed's time",
    )
    ap.add_argument(
        "--from-store",
        action="store_true",
        help="run nothing: the table of what --store (and --work's diagnostics) already hold, e.g. seeds run apart",
    )
    ap.add_argument(
        "--no-diagnose",
        dest="diagnose",
        action="store_false",
        help="skip lwbench diagnose (the network's AUC and precision; a fifth of a seed's time)",
    )
    ap.add_argument("--precisions", type=float, nargs="+", default=[0.2, 0.4, 0.6, 0.8])
    ap.add_argument("--store", type=Path, default=Path("lwbench-results/poconet_table.sqlite"))
    ap.add_argument("--work", type=Path, default=Path("lwbench-results/poconet_labels"))
    ap.add_argument("--weights", default="shipped")
    ap.add_argument("--scene", default=PROTOCOL["scene"])
    ap.add_argument("--sensor", default="auto")
    ap.add_argument("--json", type=Path, help="also write every row here")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    everything = {}
    for ratio in args.ratios:
        curve = not args.no_curve and any(abs(ratio - c) < 1e-3 for c in args.curve_ratios)
        rows = [r for seed in args.seeds for r in one_seed(args, seed, ratio, curve)]
        everything[f"{ratio:.4f}"] = rows
        print(
            f"\n### sim {args.scene}, sensor {args.sensor}, budget {ratio:.4f} of every scan (raw keeps all); "
            f"held-out seeds {args.seeds}, {args.frames} frames per drive\n"
        )
        print(table(rows, args.seeds), flush=True)
    if args.json:
        args.json.write_text(json.dumps(everything, indent=1, default=float))


if __name__ == "__main__":
    main()
