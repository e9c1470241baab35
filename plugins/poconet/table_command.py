"""``lwbench poconet-table``: PocoNet's Table I on held-out simulated drives, with per-seed paired
differences to random (docs/poconet.md §6; registered with PocoNet's other commands through
``lwbench_register_commands``).

    lwbench poconet-table [--seeds 100,101,102,103,104] [--frames 30] [--ratios 1/12,1/24]
        [--curve-ratios 1/12] [--json OUT] [--store PATH]
    lwbench poconet-table --seeds 101 --no-curve --no-controls --no-diagnose  # headline rows only
    lwbench poconet-table --seeds 100,101 --from-store  # one table of seeds run apart
    lwbench poconet-table --scene indoor --seeds 100 --no-curve     # another scene
    lwbench poconet-table --sensor os1-128 --seeds 100 --no-curve   # ... or another sensor

For each held-out seed: the street of the localization protocol (two drives: the map is built
from the first drive's selected points, the second is tracked); labels of both definitions with
``lwbench label`` (``mapping``: counts from the mapping drive only, what a robot has; ``all``:
counts from both drives, non-causal for the tracked one); then ``lwbench run`` at each budget of

- raw (the paper's Origin), random, harris3d, iss, sift3d, poconet;
- poconet's two controls: ``score=random`` (the same ground quota and spatial balance, random
  order instead of P(high)) and ``cell=0`` (P(high) without spatial balance); with ``--scores
  DIR``, a third: ``score=file``, the same rule ranking by the scores of ``lwbench
  poconet-ceiling``'s features' model (better than the network's: do better scores help?);
- the oracle on each label definition, and -- at the ``--curve-ratios`` -- the noisy oracle on the
  ``mapping`` labels at ``--precisions`` with the oracle's rule (``class``) and with poconet's rule
  (``score``);

and ``lwbench diagnose poconet`` for the network's AUC and precision against both definitions.
Each step is an ``lwbench`` command of its own (a child process, as a user would type it), so the
store holds what ``lwbench leaderboard`` shows. Prints Markdown: per method the translation ATE
rmse of every seed, mean ± std, the per-seed difference to random and on how many seeds it beats
random; rotation error, map points, r_c.

No ``from __future__ import annotations``: typer reads the annotations at run time.
"""

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from lwbench import LwbenchError, ParameterError

__all__ = ["register", "table"]

PROTOCOL = {"scene": "urban", "traversals": 2, "noise": 0.02, "distortion": "true"}
MAIN = ("raw", "random", "harris3d", "iss", "sift3d", "poconet")
ORDER = (
    "raw",
    "random",
    "harris3d",
    "iss",
    "sift3d",
    "poconet",
    "poconet, score=random (control)",
    "poconet, cell=0 (no balance)",
    "poconet, score=features' model (control)",
    "oracle (mapping)",
    "oracle (all)",
)


@dataclass(frozen=True)
class Study:
    """What one ``lwbench poconet-table`` call runs (its options)."""

    frames: int
    scene: str
    sensor: str
    weights: str
    store: Path
    work: Path
    controls: bool
    diagnose: bool
    from_store: bool
    precisions: tuple[float, ...]
    scores: Path | None = None


def lwbench(*args: str) -> str:
    """Run one ``lwbench`` command in a child process; its stdout."""
    res = subprocess.run([sys.executable, "-m", "lwbench.cli", *args], capture_output=True, text=True)
    if res.returncode:
        typer.echo(f"{res.stdout[-2000:]}\n{res.stderr[-2000:]}", err=True)
        last = (res.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise LwbenchError(f"lwbench {' '.join(args[:2])} ... failed (exit status {res.returncode}): {last}")
    return res.stdout


def numbers(text: str, option: str, kind: type = float) -> tuple:
    """``A,B,...`` -> the numbers (``1/12`` reads as a fraction)."""
    out = []
    for word in (w.strip() for w in text.split(",")):
        if not word:
            continue
        try:
            if "/" in word and kind is float:
                num, den = word.split("/", 1)
                out.append(float(num) / float(den))
            else:
                out.append(kind(word))
        except (ValueError, ZeroDivisionError):
            raise ParameterError(f"{option} {text!r}: {word!r} is not a{'n integer' if kind is int else ' number'}") \
                from None
    return tuple(out)


def row_name(entry: dict, labels: dict[str, str]) -> str:
    """The table's name of a leaderboard entry (the oracle by its label definition)."""
    p, codec = entry["params"], entry["codec"]
    if codec == "poconet":
        if p.get("score") == "random":
            return "poconet, score=random (control)"
        if p.get("score") == "file":
            return "poconet, score=features' model (control)"
        return "poconet, cell=0 (no balance)" if p.get("cell") == 0 else "poconet"
    if codec == "oracle":
        which = next((k for k, v in labels.items() if Path(p["labels"]) == Path(v)), "?")
        rule = "" if p.get("rule", "class") == "class" else f", rule {p['rule']}"
        prec = "" if p.get("precision") is None else f", noisy p={p['precision']:g}"
        return f"oracle ({which}{rule}{prec})"
    return codec


def one_seed(study: Study, seed: int, ratio: float, curve: bool) -> list[dict]:
    protocol = {**PROTOCOL, "scene": study.scene, "sensor": study.sensor, "frames": study.frames, "seed": seed}
    ds = [a for k, v in protocol.items() for a in ("--dataset-param", f"{k}={v}")]
    tag = f"{study.scene}-{study.sensor}-{study.frames}-seed-{seed}"
    labels = {d: str(study.work / f"{tag}-{d}") for d in ("mapping", "all")}
    for d, folder in labels.items():
        if not study.from_store and not (Path(folder) / "labels.json").exists():
            lwbench("label", "sim", "--out", folder, *ds, "--counts-from", d)
    common = ["run", "--dataset", "sim", *ds, "--seed", str(seed), "--store", str(study.store), "--columns", "ate_rmse"]
    main = [*common]
    for s in MAIN:
        main += ["--codec", s] + ([] if s == "raw" else ["--param", f"{s}.ratio={ratio}"])
    main += ["--param", f"poconet.weights={study.weights}"]
    if study.controls:
        main += ["--param", "poconet.score=p_high,random"]
    main += ["--codec", "oracle", "--param", f"oracle.ratio={ratio}",
             "--param", f"oracle.labels={labels['mapping']},{labels['all']}"]
    if not study.from_store:
        lwbench(*main)
    if study.controls and not study.from_store:
        lwbench(*common, "--codec", "poconet", "--param", f"poconet.ratio={ratio}",
                "--param", f"poconet.weights={study.weights}", "--param", "poconet.cell=0")
    if study.scores is not None and not study.from_store:
        folder = study.scores / f"{study.scene}-{seed}"
        lwbench(*common, "--codec", "poconet", "--param", f"poconet.ratio={ratio}",
                "--param", f"poconet.weights={study.weights}", "--param", "poconet.score=file",
                "--param", f"poconet.scores={folder}")
    if curve and not study.from_store:
        ps = ",".join(f"{p:g}" for p in study.precisions)
        for rule, precisions in (("class", ps), ("score", f"{ps},1")):  # the oracle's rule, poconet's
            lwbench(*common, "--codec", "oracle", "--param", f"oracle.ratio={ratio}",
                    "--param", f"oracle.labels={labels['mapping']}", "--param", f"oracle.precision={precisions}",
                    "--param", f"oracle.rule={rule}")
    board = json.loads(lwbench("leaderboard", "--store", str(study.store), "--format", "json"))
    rows = []
    for e in board:
        if f"seed={seed}" not in e["dataset"] or f"scene={study.scene}" not in e["dataset"]:
            continue
        if study.sensor != "auto" and f"sensor={study.sensor}" not in e["dataset"]:
            continue
        if e["codec"] != "raw" and abs((e["params"].get("ratio") or 0) - ratio) > 1e-9:
            continue
        if e["codec"] == "poconet" and e["params"].get("weights") != study.weights:
            continue
        rows.append({**e, "row": row_name(e, labels), "seed": seed})
    if study.diagnose:
        out = study.work / f"{tag}-diagnose-{ratio:.4f}.json"
        if not out.exists() and not study.from_store:
            lwbench("diagnose", "poconet", "--param", f"ratio={ratio}", "--param", f"weights={study.weights}",
                    "--dataset", "sim", *ds, "--seed", str(seed), "--labels", f"mapping={labels['mapping']}",
                    "--labels", f"all={labels['all']}", "--json", str(out))
        if out.exists():
            rows.append({"row": "poconet diagnostics", "seed": seed, **json.loads(out.read_text())["labels"]})
    return rows


def _cm(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.2f}"


def table(rows: list[dict], seeds: list[int]) -> str:
    """Markdown: per method the ATE rmse per seed, mean ± std, the paired difference to random."""
    ate: dict[str, dict] = {}
    for r in rows:
        if "ate_rmse" in r:
            ate.setdefault(r["row"], {})[r["seed"]] = r
    ate = dict(sorted(ate.items(), key=lambda kv: (ORDER.index(kv[0]) if kv[0] in ORDER else len(ORDER), kv[0])))
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
    lines += _against_control(ate, seeds)
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


CONTROL = "poconet, score=random (control)"


def _against_control(ate: dict[str, dict], seeds: list[int]) -> list[str]:
    """Markdown: each ranking's paired ATE difference to poconet's random-score control (the same
    rule and budget, random order), the seeds it wins, and a one-sided sign test -- whether the
    *scores* earn their place, which the difference to plain random cannot say."""
    from scipy.stats import binomtest

    control = ate.get(CONTROL, {})
    out = []
    for name in ("poconet", "poconet, score=features' model (control)"):
        per = ate.get(name, {})
        diffs = [per[s]["ate_rmse"] - control[s]["ate_rmse"] if s in per and s in control else None for s in seeds]
        have = [d for d in diffs if d is not None]
        if not have:
            continue
        if not out:
            out = ["", f"| ranking under poconet's rule | − {CONTROL}, per seed (cm) | mean (cm) | beats the control | "
                   "sign test p (one-sided) |", "|---|---|---|---|---|"]
        wins = sum(d < 0 for d in have)
        p = binomtest(wins, len(have), 0.5, alternative="greater").pvalue
        out.append(f"| {name} | {' / '.join('–' if d is None else f'{100 * d:+.2f}' for d in diffs)} | "
                   f"{100 * np.mean(have):+.2f} | {wins}/{len(have)} | {p:.3f} |")
    return out


def register(cli: typer.Typer) -> None:
    """Add ``lwbench poconet-table``."""

    @cli.command("poconet-table")
    def poconet_table(
        seeds: Annotated[str, typer.Option(
            help="Held-out seeds, comma-separated (default: 100,101,102,103,104).", show_default=False)]
        = "100,101,102,103,104",
        frames: Annotated[int, typer.Option(help="Frames per drive.", min=1)] = 30,
        ratios: Annotated[str, typer.Option(help="Budgets, comma-separated (1/12 reads as a fraction).")]
        = "1/12,1/24",
        curve_ratios: Annotated[str, typer.Option(
            help="Budgets that get the noisy-oracle curve, comma-separated.")] = "1/12",
        no_curve: Annotated[bool, typer.Option("--no-curve", help="Skip the noisy-oracle curve.")] = False,
        no_controls: Annotated[bool, typer.Option(
            "--no-controls", help="Skip poconet's two controls (score=random, cell=0): a quarter of a seed's "
            "time.")] = False,
        no_diagnose: Annotated[bool, typer.Option(
            "--no-diagnose", help="Skip lwbench diagnose (the network's AUC and precision): a fifth of a "
            "seed's time.")] = False,
        from_store: Annotated[bool, typer.Option(
            "--from-store", help="Run nothing: the table of what --store (and --work's diagnostics) hold, "
            "e.g. seeds run apart.")] = False,
        precisions: Annotated[str, typer.Option(help="The noisy oracle's precisions, comma-separated.")]
        = "0.2,0.4,0.6,0.8",
        store: Annotated[Path, typer.Option(
            help="The results store of every run (default: poconet_table.sqlite in lwbench-results/).",
            show_default=False)] = Path("lwbench-results/poconet_table.sqlite"),
        work: Annotated[Path, typer.Option(
            help="Folder of the label folders and diagnostics (default: poconet_labels in lwbench-results/).",
            show_default=False)] = Path("lwbench-results/poconet_labels"),
        weights: Annotated[str, typer.Option(help="poconet's weights.")] = "shipped",
        scene: Annotated[str, typer.Option(help="The simulated scene.")] = PROTOCOL["scene"],
        sensor: Annotated[str, typer.Option(help="The simulated sensor.")] = "auto",
        json_out: Annotated[Path | None, typer.Option("--json", help="Also write every row here.")] = None,
        scores: Annotated[Path | None, typer.Option(
            help="Also rank by another model's scores under poconet's rule: DIR/SCENE-SEED folders written by "
            "`lwbench poconet-ceiling --write-scores DIR` (the features' model control).")] = None,
    ) -> None:
        """PocoNet's Table I on held-out simulated drives (labels, runs, diagnostics as lwbench commands):
        ATE per seed, paired differences to random; Markdown."""
        seed_list = [int(s) for s in numbers(seeds, "--seeds", int)]
        budgets, curved = numbers(ratios, "--ratios"), numbers(curve_ratios, "--curve-ratios")
        if not seed_list or not budgets:
            raise ParameterError("poconet-table: give at least one --seeds and one --ratios value")
        if from_store and not store.exists():
            raise ParameterError(f"--from-store: {store} does not exist (run the seeds first, or name --store)")
        study = Study(frames, scene, sensor, weights, store, work, not no_controls, not no_diagnose, from_store,
                      numbers(precisions, "--precisions"), scores)
        work.mkdir(parents=True, exist_ok=True)
        everything = {}
        for ratio in budgets:
            with_curve = not no_curve and any(abs(ratio - c) < 1e-3 for c in curved)
            rows = [r for seed in seed_list for r in one_seed(study, seed, ratio, with_curve)]
            everything[f"{ratio:.4f}"] = rows
            print(
                f"\n### sim {scene}, sensor {sensor}, budget {ratio:.4f} of every scan (raw keeps all); "
                f"held-out seeds {seed_list}, {frames} frames per drive\n"
            )
            print(table(rows, seed_list), flush=True)
        if json_out is not None:
            json_out.write_text(json.dumps(everything, indent=1, default=float))
