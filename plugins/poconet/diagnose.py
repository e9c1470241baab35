"""``lwbench diagnose``: the learned-selector diagnostics of :mod:`.diagnostics` on a dataset
(registered with PocoNet's other commands through ``lwbench_register_commands``).

    lwbench diagnose poconet --param ratio=0.0833 --dataset sim --dataset-param scene=urban \\
        --dataset-param traversals=2 --labels mapping=DIR1 --labels all-drives=DIR2 --curve

For every frame: the selector's kept points (and its scores, if it has a ``scores(frame)``
method) against each label definition -- base rate, ROC AUC, top-k precision, kept precision,
kept ground share. With ``--curve``, the localization error of the noisy oracle at each
``--precision``, of the selector itself and of ``random`` at the same budget, and the precision
from which the noisy oracle beats random.

No ``from __future__ import annotations``: typer reads the annotations at run time.
"""

import json
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from lwbench import ParameterError, SelectionCodec, SequenceEvaluation, make_codec, open_dataset, sequence_metric

from .diagnostics import LabelFolder, crossing, frame_diagnostics, noisy_oracle_curve, summarize

__all__ = ["diagnose_selector", "register"]

DEFAULT_PRECISIONS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)


def _selector(name: str, params: dict[str, Any], seed: int) -> SelectionCodec:
    codec = make_codec(name, params, seed=seed)
    if not isinstance(codec, SelectionCodec):
        raise ParameterError(f"diagnose: {name} is not a selection codec")
    return codec


def _assignments(words: list[str], option: str) -> dict[str, str]:
    out = {}
    for word in words:
        key, sep, value = word.partition("=")
        if not sep or not key:
            raise ParameterError(f"{option} {word!r}: expected NAME=VALUE")
        out[key] = value
    return out


def diagnose_selector(
    dataset,
    codec,
    labels: dict[str, Any],
    curve_labels: str | None = None,
    precisions: tuple[float, ...] = DEFAULT_PRECISIONS,
    ground_share: float = 0.1,
    seed: int = 0,
    frames: list[int] | None = None,
    rules: tuple[str, ...] = ("class",),
    cell: float | None = None,
) -> dict[str, Any]:
    """The diagnostics as a dict (what ``--json`` writes): per label definition the summary of
    :func:`~.diagnostics.summarize`; with ``curve_labels``, the noisy-oracle
    curve of each rule and the selector's and random's localization values on the same frames.
    ``cell`` (the ``"score"`` rule's balance) defaults to the codec's own ``cell``, else 3 m."""
    idx = list(range(len(dataset))) if frames is None else list(frames)
    per: dict[str, list] = {name: [] for name in labels}
    decoded = []
    for i in idx:
        f = dataset[i]
        kept = np.asarray(codec.select(f), dtype=np.int64)
        decoded.append(np.asarray(f.points[kept], dtype=np.float32))
        scores = codec.scores(f)
        for name, folder in labels.items():
            per[name].append(frame_diagnostics(folder.classes(i, len(f)), kept, scores))
    out: dict[str, Any] = {
        "codec": codec.name,
        "params": codec.config,
        "dataset": dataset.identity(),
        "frames": len(idx),
        "labels": {n: summarize(v) for n, v in per.items()},
    }
    if curve_labels is None:
        return out
    folder = labels[curve_labels]
    metric = sequence_metric("localization")
    cache: dict = {}
    own = metric.compute(SequenceEvaluation(dataset, idx, decoded, codec.name, codec.config, seed, _cache=cache))
    random_params = {k: codec.config[k] for k in ("ratio", "points") if codec.config.get(k) is not None}
    rnd = _selector("random", random_params, seed)
    rnd_decoded = [np.asarray(dataset[i].points[rnd.select(dataset[i])], dtype=np.float32) for i in idx]
    ref = metric.compute(SequenceEvaluation(dataset, idx, rnd_decoded, "random", rnd.config, seed, _cache=cache))
    base = out["labels"][curve_labels]["base_rate"]
    ps = sorted({round(base, 4), *(p for p in precisions if p > base)})
    cell = float(codec.config.get("cell", 3.0)) if cell is None else cell
    key = "ate_rmse"
    out["curve"] = {
        "labels": curve_labels,
        "ground_share": ground_share,
        "cell": cell,
        "selector": own,
        "random": ref,
        "rules": {},
    }
    for rule in rules:
        curve = noisy_oracle_curve(
            dataset,
            idx,
            lambda f: folder.classes(f.index, len(f)),
            codec.budget,
            ps,
            metric,
            ground_share,
            seed,
            cache,
            rule,
            cell,
        )
        pairs = [(c.precision, c.values[key]) for c in curve if c.values.get(key) is not None]
        out["curve"]["rules"][rule] = {
            "points": [{"precision": c.precision, **c.values} for c in curve],
            "beats_random_from": crossing(pairs, ref[key]) if ref.get(key) is not None else None,
        }
    return out


def _print(result: dict[str, Any]) -> None:
    print(f"\n{result['codec']} on {result['dataset']} ({result['frames']} frames)\n")
    print("| labels | base rate | AUC | top-k precision | kept precision | kept ground share |")
    print("|---|---|---|---|---|---|")
    for name, s in result["labels"].items():
        print(
            f"| {name} | {s['base_rate']:.3f} | {s['auc']:.3f} | {s['top_k_precision']:.3f} | "
            f"{s['kept_precision']:.3f} | {s['kept_ground_share']:.3f} |"
        )
    curve = result.get("curve")
    if not curve:
        return
    print(
        f"\nnoisy oracle on the {curve['labels']!r} labels (ground share {curve['ground_share']}; rule 'class': "
        f"the oracle's, 'score': ranked with {curve['cell']} m spatial balance):\n"
    )
    print("| selection | precision | ATE rmse (m) | ATE mean (m) | rot error (deg) |")
    print("|---|---|---|---|---|")
    for rule, c in curve["rules"].items():
        for p in c["points"]:
            print(
                f"| noisy oracle, rule {rule} | {p['precision']:.3f} | {p['ate_rmse']:.4f} | {p['ate_mean']:.4f} | "
                f"{p['rot_err_deg']:.4f} |"
            )
    own, ref = curve["selector"], curve["random"]
    prec = result["labels"][curve["labels"]]["kept_precision"]
    print(
        f"| {result['codec']} | {prec:.3f} (kept) | {own['ate_rmse']:.4f} | {own['ate_mean']:.4f} | "
        f"{own['rot_err_deg']:.4f} |"
    )
    print(f"| random | – | {ref['ate_rmse']:.4f} | {ref['ate_mean']:.4f} | {ref['rot_err_deg']:.4f} |\n")
    for rule, c in curve["rules"].items():
        cross = c["beats_random_from"]
        print(
            f"rule {rule}: the noisy oracle beats random from precision "
            + (f"{cross:.3f}" if cross is not None else "– (not even at 1.0)")
        )


def register(cli) -> None:
    """Add ``lwbench diagnose``."""

    @cli.command("diagnose")
    def diagnose(
        codec: Annotated[str, typer.Argument(help="A selection codec (its scores are used if it has scores()).")],
        labels: Annotated[
            list[str],
            typer.Option(
                "--labels", help="NAME=DIR: a label folder from `lwbench label` (repeat for several definitions)."
            ),
        ],
        param: Annotated[list[str], typer.Option("--param", help="KEY=VALUE of the codec.")] = [],  # noqa: B006
        dataset: Annotated[str | None, typer.Option(help="Registered dataset name or a path.")] = None,
        dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE.")] = [],  # noqa: B006
        curve: Annotated[bool, typer.Option(help="Also the noisy-oracle curve (localization, slower).")] = False,
        curve_labels: Annotated[
            str | None, typer.Option(help="Label definition of the curve (default: the first --labels).")
        ] = None,
        precision: Annotated[
            list[float], typer.Option("--precision", help="Precisions of the curve (the base rate is always added).")
        ] = [],  # noqa: B006
        curve_rule: Annotated[
            list[str],
            typer.Option(
                "--curve-rule", help="'class' (the oracle's rule) and/or 'score' (ground quota, then balanced ranking)."
            ),
        ] = [],  # noqa: B006
        cell: Annotated[float | None, typer.Option(help="Cell (m) of the 'score' rule (default: the codec's).")] = None,
        ground_share: Annotated[float, typer.Option(help="The noisy oracle's ground quota.", min=0, max=1)] = 0.1,
        frames: Annotated[int | None, typer.Option(help="Only the first N frames.", min=1)] = None,
        seed: Annotated[int, typer.Option(help="Seed of the dataset, the codecs and the corruption.")] = 0,
        json_out: Annotated[Path | None, typer.Option("--json", help="Also write the result here.")] = None,
    ) -> None:
        """Diagnostics of a learned selector: AUC and precision against each label definition,
        and the noisy-oracle curve (what precision beats random)."""
        ds = open_dataset(dataset, list(dataset_param), seed=seed)
        folders = {name: LabelFolder(path) for name, path in _assignments(labels, "--labels").items()}
        if not folders:
            raise ParameterError("diagnose: give at least one --labels NAME=DIR")
        chosen = curve_labels or next(iter(folders))
        if chosen not in folders:
            raise ParameterError(f"diagnose: --curve-labels {chosen!r} is none of {sorted(folders)}")
        sel = _selector(codec, _assignments(param, "--param"), seed)
        idx = list(range(min(len(ds), frames) if frames else len(ds)))
        result = diagnose_selector(
            ds,
            sel,
            folders,
            chosen if curve else None,
            tuple(precision) or DEFAULT_PRECISIONS,
            ground_share,
            seed,
            idx,
            tuple(curve_rule) or ("class",),
            cell,
        )
        _print(result)
        if json_out is not None:
            json_out.parent.mkdir(parents=True, exist_ok=True)
            json_out.write_text(json.dumps(result, indent=1, default=float))
