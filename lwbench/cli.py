"""The ``lwbench`` command line (typer + rich). Forms and metric ids follow DESIGN.md.

User errors (unknown codec, bad parameter, unreadable file) print one clear line and exit 2;
a traceback means a bug in lwbench or a plugin.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from lwbench.errors import LwbenchError
from lwbench.leaderboard import DEFAULT_MIN_COVERAGE
from lwbench.registry import Registry, get_registry

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="lwbench: benchmark LiDAR point-cloud reduction codecs on one leaderboard.",
    pretty_exceptions_enable=False,
)
# Off a terminal (CI logs, pipes) rich would wrap tables at 80 columns; leaderboards are wide.
console = Console(width=None if sys.stdout.isatty() else 180)
err_console = Console(stderr=True, soft_wrap=True)

DEFAULT_STORE = Path("lwbench-results/results.sqlite")
DEFAULT_DATASET = "sim"
# The main job: every built-in codec whose defaults encode a scan in well under a second on 2
# cores, so `lwbench run` alone finishes in about a minute. gmm is left out: its default fit
# (K=200 full covariances by EM on every point) takes 10-70 s per scan on 2 cores; ask for it with
# --codec gmm (see docs/gmm.md).
DEFAULT_CODECS = ("raw", "random", "voxel", "draco", "rangeimage", "vsgp", "harris3d", "iss", "sift3d")

_state = {"strict": False}


def _fail(message: str) -> None:
    err_console.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(2)


def _registry() -> Registry:
    reg = get_registry()
    if _state["strict"]:
        try:
            reg.raise_failures()
        except LwbenchError as exc:
            _fail(str(exc))
    elif reg.failures:
        names = ", ".join(f.plugin for f in reg.failures)
        err_console.print(
            f"[yellow]warning:[/] plugin(s) failed to load and were skipped: {names} "
            "(`lwbench list` shows why; --strict makes this fatal)"
        )
    return reg


@app.callback()
def _global_options(
    strict: Annotated[bool, typer.Option("--strict", help="Fail if any plugin fails to load (for CI).")] = False,
) -> None:
    _state["strict"] = strict


def _parse_kv(items: list[str], what: str) -> dict[str, str]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            _fail(f"{what} must look like KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


# ------------------------------------------------------------------------------------- list
@app.command("list")
def list_plugins(
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Codecs, datasets and metrics with their parameters and the package providing each."""
    reg = _registry()
    data = {
        "codecs": [{**c.describe(), "provider": reg.providers[("codec", n)]} for n, c in sorted(reg.codecs.items())],
        "datasets": [
            {**d.describe(), "provider": reg.providers[("dataset", n)]} for n, d in sorted(reg.datasets.items())
        ],
        "metrics": [
            {
                "name": n,
                "kind": kind,
                "ids": list(m.ids),
                "description": m.description,
                "provider": reg.providers[("metric", n)],
            }
            for kind, table in (("frame", reg.frame_metrics), ("sequence", reg.sequence_metrics))
            for n, m in sorted(table.items())
        ],
        "failures": [{"plugin": f.plugin, "target": f.target, "error": f.error} for f in reg.failures],
    }
    if as_json:
        print(json.dumps(data, indent=2, default=str))
        return
    for title, items in (("Codecs", data["codecs"]), ("Datasets", data["datasets"])):
        table = Table(title=title, title_justify="left")
        for col in ("name", "kind" if title == "Codecs" else "description", "parameters", "provider"):
            table.add_column(col)
        for it in items:
            params = ", ".join(
                f"{p['name']}={p['default']}"
                + (f" {p['range']}" if "range" in p else "")
                + (f" {{{'|'.join(p['choices'])}}}" if "choices" in p else "")
                for p in it["params"]
            )
            table.add_row(it["name"], it.get("kind", it["description"]), params, it["provider"])
        console.print(table)
    table = Table(title="Metrics", title_justify="left")
    for col in ("name", "kind", "ids", "provider"):
        table.add_column(col)
    for m in data["metrics"]:
        table.add_row(m["name"], m["kind"], ", ".join(m["ids"]), m["provider"])
    console.print(table)
    if data["failures"]:
        table = Table(title="Plugins that failed to load", title_justify="left", style="red")
        for col in ("plugin", "target", "error"):
            table.add_column(col)
        for f in data["failures"]:
            table.add_row(f["plugin"], f["target"], f["error"])
        console.print(table)


# -------------------------------------------------------------------------------------- run
def _dataset_spec(reg: Registry, dataset: str, params: dict[str, str]):
    from lwbench.runner import DatasetSpec

    path = Path(dataset).expanduser()
    if dataset not in reg.datasets and (path.exists() or "/" in dataset or path.suffix):
        if not path.exists():
            _fail(f"dataset path {dataset} does not exist")
        for name, cls in reg.datasets.items():
            if cls.sniff(path):
                return DatasetSpec(name, {**params, "path": str(path.resolve())})
        _fail(f"no installed loader recognises {dataset} (KITTI folder, PCD/PLY folder or scan file)")
    reg.dataset(dataset)  # raises a clear error for an unknown name
    return DatasetSpec(dataset, params)


def _codec_values(reg: Registry, codecs: list[str], params: list[str]) -> dict[str, dict[str, list[str]]]:
    values: dict[str, dict[str, list[str]]] = {c: {} for c in codecs}
    for item in params:
        target, sep, value = item.partition("=")
        codec, dot, key = target.partition(".")
        if not sep or not dot:
            _fail(f"--param must look like CODEC.KEY=VALUE[,VALUE...], got {item!r}")
        if codec not in values:
            _fail(f"--param {item!r} is for codec {codec!r}, which is not in this run's --codec list")
        values[codec][key] = [v for v in value.split(",")]
    for c in codecs:
        reg.codec(c)
    return values


@app.command()
def run(
    dataset: Annotated[str, typer.Option(help="Registered dataset name or a path (auto-detected).")] = DEFAULT_DATASET,
    dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE for the dataset.")] = [],  # noqa: B006
    codec: Annotated[list[str], typer.Option("--codec", help="Codec to run (repeat). Default: the main set.")] = [],  # noqa: B006
    param: Annotated[list[str], typer.Option("--param", help="CODEC.KEY=V1[,V2...]: sweep values.")] = [],  # noqa: B006
    frames: Annotated[int | None, typer.Option(help="Evaluate only the first N frames.", min=1)] = None,
    store: Annotated[Path, typer.Option(help="SQLite results store.")] = DEFAULT_STORE,
    workers: Annotated[int, typer.Option(help="Parallel worker processes (frames in parallel).", min=1)] = 1,
    seed: Annotated[int, typer.Option(help="Seed for every codec/dataset that declares one.")] = 0,
    sequence_metrics: Annotated[bool, typer.Option(help="Localization/occupancy metrics when poses exist.")] = True,
    retry_failed: Annotated[bool, typer.Option(help="Re-evaluate stored failures.")] = False,
    force: Annotated[bool, typer.Option("--force", help="Recompute every row, even those already stored.")] = False,
    metric_param: Annotated[
        list[str], typer.Option("--metric-param", help="METRIC.KEY=VALUE, e.g. geometry.peak=59.70 (part of the key).")
    ] = [],  # noqa: B006
    sort: Annotated[str, typer.Option(help="Metric to sort the printed leaderboard by.")] = "ratio",
    min_coverage: Annotated[
        float, typer.Option(help="Flag configurations whose coverage is below this.", min=0, max=1)
    ] = DEFAULT_MIN_COVERAGE,
) -> None:
    """Evaluate codecs on a dataset; every result lands in the store; print the leaderboard."""
    from lwbench.leaderboard import build_leaderboard
    from lwbench.runner import Runner, expand_codec_configs
    from lwbench.store import ResultStore

    reg = _registry()
    try:
        ds_params = _parse_kv(dataset_param, "--dataset-param")
        spec = _dataset_spec(reg, dataset, ds_params)
        if "seed" in {p.name for p in reg.dataset(spec.name).params} and "seed" not in spec.params:
            spec = type(spec)(spec.name, {**spec.params, "seed": str(seed)})
        codecs = list(dict.fromkeys(codec)) or [c for c in DEFAULT_CODECS if c in reg.codecs]
        values = _codec_values(reg, codecs, param)
        configs = [cfg for c in codecs for cfg in expand_codec_configs(reg.codec(c), values[c], seed)]
        metric_params = _metric_params(reg, metric_param)
        with ResultStore(store) as results:
            runner = Runner(
                results,
                spec,
                configs,
                frames=frames,
                seed=seed,
                workers=workers,
                sequence_metrics=sequence_metrics,
                retry_failed=retry_failed,
                force=force,
                metric_params=metric_params,
                registry=reg,
            )
            n_total = len(runner.frame_indices) * len(configs)
            console.print(
                f"[bold]lwbench run[/]: {spec.label} · {len(runner.frame_indices)} frame(s) · "
                f"{len(configs)} codec configuration(s) · store {store}"
            )
            with Progress(
                TextColumn("[progress.description]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=console,
                transient=False,
                disable=not sys.stdout.isatty(),
            ) as progress:
                task = progress.add_task("evaluating", total=None)

                def on_progress(done: int, total: int, row) -> None:
                    progress.update(
                        task,
                        total=total,
                        completed=done,
                        description=f"{row.codec} frame {row.frame}" if row else "evaluating",
                    )

                summary = runner.run(on_progress)
            console.print(
                f"evaluated {summary.evaluated}, cached {summary.skipped} of {n_total}; "
                f"{summary.failed} failure(s); {summary.sequence_rows} sequence row(s)"
            )
            for f in summary.failures[:10]:
                err_console.print(f"[red]failed:[/] {f}")
            if summary.interrupted:
                err_console.print(
                    "[yellow]interrupted:[/] finished rows are stored; run the same command again to resume"
                )
                raise typer.Exit(130)
            entries = build_leaderboard(
                results, sort=sort, defaults=_defaults(reg), keys=runner.keys(), min_coverage=min_coverage
            )
            console.print(f"dataset: {spec.label}")
            _print_table(entries, sort)
    except LwbenchError as exc:
        _fail(str(exc))


def _metric_params(reg: Registry, items: list[str]) -> dict[str, dict]:
    """``METRIC.KEY=VALUE`` options -> {metric: {key: value}}, checked against the registry."""
    out: dict[str, dict] = {}
    for item in items:
        target, sep, value = item.partition("=")
        metric, dot, key = target.partition(".")
        if not sep or not dot:
            _fail(f"--metric-param must look like METRIC.KEY=VALUE, got {item!r}")
        out.setdefault(metric.strip(), {})[key.strip()] = value.strip()
    reg.check_metric_params(out)
    return out


def _defaults(reg: Registry) -> dict[str, dict]:
    return {name: {p.name: p.default for p in cls.all_params()} for name, cls in reg.codecs.items()}


def _print_table(entries, sort: str) -> None:
    from lwbench.leaderboard import DEFAULT_COLUMNS, present_columns, table_rows

    cols = present_columns(entries, DEFAULT_COLUMNS)
    if sort not in cols and any(e.value(sort) is not None for e in entries):
        cols = (sort, *cols)
    header, rows = table_rows(entries, cols)
    table = Table(title=f"Leaderboard (mean over frames; sorted by {sort})", title_justify="left")
    for h in header:
        table.add_column(h, justify="left" if h in ("dataset", "codec") else "right", overflow="fold")
    for r in rows:
        table.add_row(*r)
    console.print(table)
    for e in entries:
        for err in e.errors:
            err_console.print(f"[red]{e.label}[/]: {err}")


# ------------------------------------------------------------------------------ leaderboard
@app.command()
def leaderboard(
    store: Annotated[Path, typer.Option(help="SQLite results store.")] = DEFAULT_STORE,
    dataset: Annotated[str | None, typer.Option(help="Only this dataset (name, label or id).")] = None,
    sort: Annotated[str, typer.Option(help="Metric id to sort by.")] = "ratio",
    format: Annotated[str, typer.Option("--format", help="table | md | csv | json")] = "table",
    columns: Annotated[str | None, typer.Option(help="Comma-separated metric ids to show (table/md).")] = None,
    min_coverage: Annotated[
        float, typer.Option(help="Flag configurations whose coverage is below this.", min=0, max=1)
    ] = DEFAULT_MIN_COVERAGE,
) -> None:
    """Aggregate stored rows (mean, median, p95 per codec configuration)."""
    from lwbench.leaderboard import (
        DEFAULT_COLUMNS,
        build_leaderboard,
        present_columns,
        to_csv,
        to_json,
        to_markdown,
    )
    from lwbench.store import ResultStore

    if format not in ("table", "md", "csv", "json"):
        _fail(f"--format must be table, md, csv or json, got {format!r}")
    if not store.exists():
        _fail(f"no results store at {store} (run `lwbench run` first)")
    try:
        with ResultStore(store, readonly=True) as results:
            entries = build_leaderboard(
                results, dataset=dataset, sort=sort, defaults=_defaults(_registry()), min_coverage=min_coverage
            )
    except LwbenchError as exc:
        _fail(str(exc))
    if not entries:
        _fail("no results" + (f" for dataset {dataset!r}" if dataset else "") + f" in {store}")
    if format == "json":
        print(to_json(entries))
    elif format == "csv":
        print(to_csv(entries), end="")
    else:
        wanted = tuple(c.strip() for c in columns.split(",")) if columns else DEFAULT_COLUMNS
        cols = wanted if columns else present_columns(entries, wanted)
        if format == "md":
            print(to_markdown(entries, cols), end="")
        else:
            _print_table(entries, sort)


# ---------------------------------------------------------------------------------- inspect
@app.command()
def inspect(file: Annotated[Path, typer.Argument(help="A payload, scan file, dataset folder or store.")]) -> None:
    """Say what a file holds: an lwbench payload, a scan, a dataset folder or a results store."""
    from lwbench.inspect import describe

    if not file.exists():
        _fail(f"{file} does not exist")
    try:
        info = describe(file, _registry())
    except LwbenchError as exc:
        _fail(str(exc))
    table = Table(title=str(file), title_justify="left", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value", overflow="fold")
    for k, v in info.items():
        table.add_row(k, v if isinstance(v, str) else json.dumps(v, default=str))
    console.print(table)


# --------------------------------------------------------------------------------- simulate
@app.command()
def simulate(
    scene: Annotated[str, typer.Argument(help="Scene: tunnel, urban or indoor.")],
    out: Annotated[Path, typer.Option(help="Output folder (KITTI odometry layout).")],
    frames: Annotated[int | None, typer.Option(help="Number of scans.", min=1)] = None,
    seed: Annotated[int, typer.Option(help="Scene and noise seed.")] = 0,
    sensor: Annotated[str | None, typer.Option(help="Sensor preset (default: the scene's).")] = None,
) -> None:
    """Write a simulated sequence to disk in KITTI layout (readable by lwbench and other tools)."""
    from lwbench.io import write_kitti_sequence

    reg = _registry()
    try:
        params: dict[str, object] = {"scene": scene, "seed": seed}
        if frames is not None:
            params["frames"] = frames
        if sensor is not None:
            params["sensor"] = sensor
        ds = reg.dataset("sim")(**params)
        with Progress(console=console, disable=not sys.stdout.isatty()) as progress:
            task = progress.add_task(f"simulating {scene}", total=len(ds))
            scans = []
            for f in ds:
                scans.append(f)
                progress.advance(task)
        write_kitti_sequence(scans, out)
    except LwbenchError as exc:
        _fail(str(exc))
    console.print(f"wrote {len(scans)} scans of {scene!r} to {out} (run: lwbench run --dataset {out})")


def main() -> None:
    """The ``lwbench`` executable: any lwbench error that escapes a command (a missing library,
    a bad input found late) is one line on stderr and exit status 2, never a traceback."""
    try:
        app()
    except LwbenchError as exc:
        err_console.print(f"[bold red]error:[/] {exc}")
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
