"""The ``lwbench`` command line (typer + rich). Forms and metric ids follow DESIGN.md.

User errors (unknown codec, bad parameter, unreadable file) print one clear line and exit 2;
a traceback means a bug in lwbench or a plugin. Commands only parse words and print: planning
a run is :func:`lwbench.run.plan_run`, running it :class:`lwbench.run.Runner`, the board
:func:`lwbench.leaderboard.build_leaderboard`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
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
console = Console(width=None if sys.stdout.isatty() else 200)
err_console = Console(stderr=True, soft_wrap=True)

DEFAULT_STORE = Path("lwbench-results/results.sqlite")
DEFAULT_TIMEOUT = 3600.0  # lwbench.run.DEFAULT_TIMEOUT_S (not imported here: the CLI starts fast)

_state = {"strict": False}


def _fail(message: str) -> None:
    err_console.print(f"[bold red]error:[/] {message}", markup=True, highlight=False)
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


def _version(value: bool) -> None:
    if value:
        from lwbench.version import __version__

        print(f"lwbench {__version__}")
        raise typer.Exit()


@app.callback()
def _global_options(
    strict: Annotated[bool, typer.Option("--strict", help="Fail if any plugin fails to load (for CI).")] = False,
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    _state["strict"] = strict


# ------------------------------------------------------------------------------------- list
@app.command("list")
def list_plugins(
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Codecs, datasets and metrics with their parameters and the package providing each."""
    from lwbench.metric import as_metric_id

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
                "ids": [str(i) for i in m.ids],
                "id_info": [as_metric_id(i).describe() for i in m.ids],
                "version": m.version,
                "params": [p.describe() for p in m.params],
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
@app.command()
def run(
    dataset: Annotated[
        str | None, typer.Option(help="Registered dataset name or a path (auto-detected). Default: sim.")
    ] = None,
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
    columns: Annotated[str | None, typer.Option(help="Comma-separated metric ids to show.")] = None,
    min_coverage: Annotated[
        float, typer.Option(help="Flag configurations whose coverage is below this.", min=0, max=1)
    ] = DEFAULT_MIN_COVERAGE,
    config: Annotated[
        Path | None, typer.Option(help="A TOML run file: datasets x codecs x grids x seeds (see docs).")
    ] = None,
    isolate: Annotated[
        bool, typer.Option("--isolate/--in-process",
                           help="Evaluate in worker processes with a timeout and a memory ceiling (default).")
    ] = True,
    timeout: Annotated[
        float, typer.Option(help="Seconds one evaluation may take before its worker is killed (0: no limit).", min=0)
    ] = DEFAULT_TIMEOUT,
    memory_limit: Annotated[
        int | None, typer.Option(help="MB of memory per worker (default: 80% of the machine's, shared).", min=1)
    ] = None,
    executor: Annotated[str, typer.Option(help="local, or ray: evaluations as Ray tasks (lwbench[ray]).")] = "local",
    address: Annotated[
        str | None, typer.Option(help="Ray cluster address (--executor ray; default: start a local Ray).")
    ] = None,
) -> None:
    """Evaluate codecs on a dataset; every result lands in the store; print the leaderboard."""
    from lwbench.leaderboard import build_leaderboard
    from lwbench.run import Runner, parse_assignments, parse_sweeps, plan_run, preflight
    from lwbench.run.config import load_run_file
    from lwbench.store import ResultStore

    reg = _registry()
    try:
        if config is not None:
            if dataset or dataset_param or codec or param:
                _fail("--config describes the datasets and codecs: leave out --dataset, --codec and --param")
            run_file = load_run_file(config, reg)
            plans = list(run_file.plans)
            if run_file.store is not None and store == DEFAULT_STORE:
                store = run_file.store
            workers = max(workers, run_file.workers)
        else:
            codecs = list(dict.fromkeys(codec))
            owners = codecs or sorted(n for n, c in reg.codecs.items() if c.in_default_run)
            plans = [plan_run(
                reg,
                dataset=dataset,
                dataset_params=parse_assignments(dataset_param, "--dataset-param"),
                codecs=codecs,
                sweeps=parse_sweeps(param, owners, "--param"),
                frames=frames,
                seed=seed,
                metric_params=parse_sweeps_single(metric_param, reg),
                sequence_metrics=sequence_metrics,
            )]
        info = reg.metric_info()
        wanted = _columns(columns, info, reg)
        if executor not in ("local", "ray"):
            _fail(f"--executor must be local or ray, got {executor!r}")
        # Everything that can be checked is, before the store is opened: a bad dataset, scan,
        # sensor file or device is one line and exit 2 with nothing written.
        checked = [preflight(reg, plan) for plan in plans]
        keys: set[str] = set()
        with ResultStore(store) as results:
            for plan, dataset in zip(plans, checked, strict=True):
                runner = Runner(results, plan, registry=reg, workers=workers, retry_failed=retry_failed, force=force,
                                isolate=isolate, timeout_s=timeout or None, memory_mb=memory_limit,
                                executor=executor, address=address, dataset=dataset)
                n_total = len(runner.frame_indices) * len(runner.configs)
                console.print(
                    f"[bold]lwbench run[/]: {escape(plan.dataset.label)} · {len(runner.frame_indices)} frame(s) · "
                    f"{len(runner.configs)} codec configuration(s) · store {escape(str(store))}"
                )
                summary = _run_with_progress(runner)
                console.print(
                    f"evaluated {summary.evaluated}, cached {summary.skipped} of {n_total}; "
                    f"{summary.failed} failure(s); {summary.sequence_rows} sequence row(s)"
                )
                for f in summary.failures[:10]:
                    err_console.print(f"[red]failed:[/] {escape(f)}", highlight=False)
                if summary.interrupted:
                    err_console.print(
                        "[yellow]interrupted:[/] finished rows are stored; run the same command again to resume"
                    )
                    raise typer.Exit(130)
                keys |= runner.keys()
            entries = build_leaderboard(results, sort=sort, info=info, keys=keys, min_coverage=min_coverage)
            if len(plans) == 1:
                console.print(f"dataset: {escape(plans[0].dataset.label)}")
            _print_table(entries, sort, wanted, info)
    except LwbenchError as exc:
        _fail(str(exc))


def parse_sweeps_single(items: list[str], reg: Registry) -> dict[str, dict[str, str]]:
    """``--metric-param METRIC.KEY=VALUE`` words (one value each)."""
    from lwbench.run import parse_sweeps

    metrics = sorted({*reg.frame_metrics, *reg.sequence_metrics})
    sweeps = parse_sweeps(items, metrics, "--metric-param", "metric")
    out: dict[str, dict[str, str]] = {}
    for metric, values in sweeps.items():
        for key, vals in values.items():
            if len(vals) != 1:
                raise LwbenchError(f"--metric-param {metric}.{key}: one value only (metrics are not swept)")
            out.setdefault(metric, {})[key] = vals[0]
    return out


def _run_with_progress(runner):
    with Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=console,
        transient=False,
        disable=not sys.stdout.isatty(),
    ) as progress:
        tasks: dict[str, int] = {}

        def on_progress(event) -> None:
            if event.phase not in tasks:
                title = "frames" if event.phase == "frames" else "sequence metrics"
                tasks[event.phase] = progress.add_task(title, total=event.total)
            row = event.row
            what = f"{row.codec} frame {row.frame}" if row.kind == "frame" else f"{row.codec} · {row.part}"
            progress.update(tasks[event.phase], total=event.total, completed=event.done, description=what)

        return runner.run(on_progress)


def _columns(columns: str | None, info, reg: Registry) -> tuple[str, ...] | None:
    from lwbench.leaderboard import check_metric_ids

    if not columns:
        return None
    wanted = tuple(c.strip() for c in columns.split(",") if c.strip())
    check_metric_ids(list(wanted), info, "--columns")
    return wanted


def _print_table(entries, sort: str, wanted: tuple[str, ...] | None, info) -> None:
    """The board in the terminal: never folds a number -- columns that do not fit are left out
    (and named), so read a wide board with --columns or --format md."""
    from lwbench.leaderboard import present_columns, table_rows

    if wanted is None:
        cols = present_columns(entries, tuple(info_id for info_id, i in info.items() if i.default))
        if sort not in cols and any(e.value(sort) is not None for e in entries):
            cols = (sort, *cols)
    else:
        cols = wanted
    header, rows = table_rows(entries, cols, info)
    width = console.width or 200
    fixed = header.index("fail") + 1
    # What rich needs per column: the widest cell, one space of padding each side, one border.
    widths = [max(len(h), *(len(r[i]) for r in rows)) + 3 if rows else len(h) + 3 for i, h in enumerate(header)]
    dropped: list[str] = []
    keep = list(range(len(header)))
    flags_col = [len(header) - 1] if header[-1] == "flags" else []
    while sum(widths[i] for i in keep) + 1 > width and len(keep) > fixed + 1 + len(flags_col):
        victim = [i for i in keep if i >= fixed and i not in flags_col][-1]
        keep.remove(victim)
        dropped.append(header[victim])
    table = Table(title=f"Leaderboard (mean over frames; sorted by {escape(sort)})", title_justify="left")
    for i in keep:
        numeric = i >= fixed and i not in flags_col
        table.add_column(escape(header[i]), justify="right" if numeric else "left", no_wrap=numeric)
    for r in rows:
        table.add_row(*(escape(r[i]) for i in keep))
    console.print(table)
    if dropped:
        names = escape(", ".join(reversed(dropped)))
        console.print(f"[dim]not shown (terminal too narrow): {names}; use --columns or --format md[/]")
    for e in entries:
        for err in e.errors:
            err_console.print(f"[red]{e.label}[/]: {err}", highlight=False)
        if e.stale:
            err_console.print(f"[dim]{e.label}: {e.stale} older row(s) scored another way are not included[/]")


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
    """Aggregate stored rows (mean, std, median, p95 per codec configuration)."""
    from lwbench.leaderboard import build_leaderboard, present_columns, to_csv, to_json, to_markdown
    from lwbench.store import ResultStore

    if format not in ("table", "md", "csv", "json"):
        _fail(f"--format must be table, md, csv or json, got {format!r}")
    if not store.exists():
        _fail(f"no results store at {store} (run `lwbench run` first)")
    reg = _registry()
    info = reg.metric_info()
    try:
        with ResultStore(store, readonly=True) as results:
            entries = build_leaderboard(results, dataset=dataset, sort=sort, info=info, min_coverage=min_coverage)
        stored_ids = {m for e in entries for m in e.stats}
        wanted = _columns(columns, {**dict.fromkeys(stored_ids), **info}, reg)
    except LwbenchError as exc:
        _fail(str(exc))
    if not entries:
        _fail("no results" + (f" for dataset {dataset!r}" if dataset else "") + f" in {store}")
    if format == "json":
        print(to_json(entries))
    elif format == "csv":
        print(to_csv(entries), end="")
    elif format == "md":
        cols = wanted or present_columns(entries, reg.default_columns())
        print(to_markdown(entries, cols, info), end="")
    else:
        _print_table(entries, sort, wanted, info)


# -------------------------------------------------------------------------------------- rd
@app.command()
def rd(
    distortion: Annotated[str, typer.Option(help="Distortion metric id (range_rmsd, chamfer, d1_psnr, ate_rmse, ...).")]
    = "range_rmsd",
    rate: Annotated[str, typer.Option(help="Rate metric id: bytes (per frame) or bits_per_point.")] = "bytes",
    store: Annotated[Path, typer.Option(help="SQLite results store.")] = DEFAULT_STORE,
    dataset: Annotated[str | None, typer.Option(help="Only this dataset (name, label or id).")] = None,
    reference: Annotated[str | None, typer.Option(help="Codec the BD-rate / BD-distortion are measured against.")]
    = None,
    at_rate: Annotated[float | None, typer.Option(help="Report each curve's distortion at this rate.")] = None,
    at_distortion: Annotated[float | None, typer.Option(help="Report each curve's rate at this distortion.")] = None,
    format: Annotated[str, typer.Option("--format", help="table | json")] = "table",
) -> None:
    """Rate-distortion from the sweep points in the store: each codec's curve, the Pareto front,
    values at equal rate / distortion (interpolated, never extrapolated) and BD-rate."""
    from lwbench.leaderboard import build_leaderboard, check_metric_ids
    from lwbench.rd import curves_from_entries, summarise
    from lwbench.store import ResultStore

    if format not in ("table", "json"):
        _fail(f"--format must be table or json, got {format!r}")
    reg = _registry()
    info = reg.metric_info()
    try:
        check_metric_ids([distortion, rate], info, "lwbench rd")
        with ResultStore(store, readonly=True) as results:
            entries = build_leaderboard(results, dataset=dataset, info=info)
        left_out: list = []
        curves = curves_from_entries(entries, distortion, rate=rate, info=info, left_out=left_out)
        unit = info[distortion].unit
        summary = summarise(curves, unit=unit, at_rate=at_rate, at_distortion=at_distortion, reference=reference)
    except LwbenchError as exc:
        _fail(str(exc))
    if not summary:
        _fail(f"no unflagged configuration in {store} has both {rate} and {distortion}")
    skipped = [{"dataset": e.dataset, "label": e.label, "reason": why} for e, why in left_out]
    if format == "json":
        print(json.dumps({"rate": rate, "distortion": distortion, "datasets": summary, "left_out": skipped}, indent=2))
        return
    d_unit, r_unit = info[distortion].unit, info[rate].unit
    for ds, s in summary.items():
        table = Table(title=f"{ds}: {distortion} [{d_unit}] against {rate} [{r_unit}]", title_justify="left")
        for col in ("codec", "points (label: rate -> distortion)", "on the front"):
            table.add_column(col)
        on_front = {(f["codec"], f["label"]) for f in s["front"]}
        for codec, pts in s["curves"].items():
            text = "; ".join(f"{p['label']}: {p['rate']:,.0f} -> {p['distortion']:.4g}" for p in pts)
            n = sum((codec, p["label"]) in on_front for p in pts)
            table.add_row(escape(codec), escape(text), f"{n} of {len(pts)}")
        console.print(table)
        for what, key, fmt in (("at_rate", at_rate, "{:.4g}"), ("at_distortion", at_distortion, "{:,.0f}")):
            if key is None:
                continue
            vals = ", ".join(f"{c} {fmt.format(v) if v is not None else 'does not reach'}" for c, v in s[what].items())
            console.print(f"{'distortion at' if what == 'at_rate' else 'rate at'} {key:g}: {escape(vals)}")
        for codec, bd in s["bd"].items():
            if "error" in bd:
                console.print(f"BD vs {reference}: {escape(codec)}: {escape(bd['error'])}")
            else:
                console.print(f"BD vs {reference}: {escape(codec)}: BD-rate {bd['bd_rate_pct']:+.1f} %, "
                              f"BD-distortion {bd['bd_distortion']:+.3g} dB")
    if skipped:
        console.print("left out: " + escape("; ".join(f"{s['label']} ({s['reason']})" for s in skipped)))


# ---------------------------------------------------------------------------------- report
@app.command()
def report(
    out: Annotated[Path, typer.Option(help="Folder for index.html and the plots (PNG + SVG).")] = Path(
        "lwbench-report"
    ),
    store: Annotated[Path, typer.Option(help="SQLite results store.")] = DEFAULT_STORE,
    dataset: Annotated[str | None, typer.Option(help="Only this dataset (name, label or id).")] = None,
    config: Annotated[
        Path | None, typer.Option(help="Run this TOML study first (cached rows are reused), then report it.")
    ] = None,
) -> None:
    """Write a self-contained HTML report: sortable leaderboard, RD curves, runtime, a gallery."""
    from lwbench.report import write_report

    if config is not None:
        from lwbench.run.config import load_run_file

        run_file = load_run_file(config, _registry())
        if run_file.store is not None and store == DEFAULT_STORE:
            store = run_file.store
        run(config=config, store=store, dataset=None, dataset_param=[], codec=[], param=[], frames=None,
            workers=run_file.workers, seed=0, sequence_metrics=True, retry_failed=False, force=False,
            metric_param=[], sort="ratio", columns=None, min_coverage=DEFAULT_MIN_COVERAGE, isolate=True,
            timeout=DEFAULT_TIMEOUT, memory_limit=None, executor="local", address=None)
    if not store.exists():
        _fail(f"no results store at {store} (run `lwbench run` first)")
    try:
        page = write_report(store, out, _registry(), dataset=dataset)
    except LwbenchError as exc:
        _fail(str(exc))
    console.print(f"wrote {page} (open it in a browser; plots as PNG and SVG beside it)")


# ---------------------------------------------------------------------------------- inspect
@app.command()
def inspect(file: Annotated[Path, typer.Argument(help="A payload, stream file, scan, dataset folder, bag or store.")]
            ) -> None:
    """Say what a file holds: an lwbench payload or stream file, a scan, a dataset folder, a ROS bag or a
    results store."""
    from lwbench.inspection import describe

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


# ------------------------------------------------- encode / decode / view / stream (issue 15)
def _dataset(reg: Registry, source: str, dataset_param: list[str], seed: int):
    """A dataset from a registered name or a path, as ``lwbench run --dataset`` resolves it."""
    from lwbench.run import parse_assignments, resolve_dataset

    spec = resolve_dataset(reg, source, parse_assignments(dataset_param, "--dataset-param"), seed)
    return spec, spec.build(reg)


@app.command()
def encode(
    source: Annotated[str, typer.Argument(help="A scan file, dataset folder, ROS bag or dataset name (sim).")],
    codec: Annotated[str, typer.Option(help="Codec to encode with.")],
    out: Annotated[Path, typer.Option(help="Output folder.")],
    param: Annotated[list[str], typer.Option("--param", help="KEY=VALUE (or CODEC.KEY=VALUE) for the codec.")] = [],  # noqa: B006
    dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE for the dataset.")] = [],  # noqa: B006
    frames: Annotated[int | None, typer.Option(help="Encode only the first N frames.", min=1)] = None,
    seed: Annotated[int, typer.Option(help="Seed, as lwbench run --seed.")] = 0,
    stream: Annotated[bool, typer.Option("--stream", help="One .lwbs stream file instead of one .lwb per frame.")]
    = False,
) -> None:
    """Write payloads: one .lwb per frame plus stream.json (codec, parameters, sensor table, index), or
    one .lwbs stream file; the bytes are what lwbench run measures and what crosses the link."""
    from lwbench.transcode import codec_config, encode_dataset

    reg = _registry()
    try:
        config = codec_config(reg, codec, param, seed)
        spec, ds = _dataset(reg, source, dataset_param, seed)
        with Progress(console=console, disable=not sys.stdout.isatty()) as progress:
            task = progress.add_task(f"encoding with {config.label}", total=None)
            summary = encode_dataset(reg, ds, config, out, stream=stream, frames=frames, source=spec.label,
                                     on_frame=lambda done, n: progress.update(task, completed=done, total=n))
    except LwbenchError as exc:
        _fail(str(exc))
    ratio = summary.raw_bytes / summary.payload_bytes if summary.payload_bytes else float("nan")
    console.print(
        f"wrote {summary.frames} frame(s), {summary.payload_bytes:,} bytes ({ratio:.1f}x smaller than float32 "
        f"x,y,z) as a {summary.layout}: {escape(str(summary.path))}"
    )


@app.command()
def decode(
    file: Annotated[Path, typer.Argument(help="A .lwbs stream file, a .lwb payload or a folder of them.")],
    out: Annotated[Path, typer.Option(help="Output folder (for --format bag: the new bag's folder).")],
    format: Annotated[str, typer.Option("--format", help="pcd | ply | bag (ROS 2)")] = "pcd",
    param: Annotated[list[str], typer.Option("--param", help="KEY=VALUE: decode-side codec setting.")] = [],  # noqa: B006
    storage: Annotated[str, typer.Option(help="Bag storage: mcap or sqlite3 (.db3).")] = "mcap",
) -> None:
    """Decode payloads into clouds named after their source frames (NAME.CODEC.pcd, with sensor.json and
    poses.txt beside them), or into a ROS 2 bag on the source's topics and stamps."""
    from lwbench.streamfile import open_payloads
    from lwbench.transcode import decode_payloads

    if not file.exists():
        _fail(f"{file} does not exist")
    reg = _registry()
    try:
        summary = decode_payloads(reg, open_payloads(file), out, fmt=format, overrides=param, storage=storage)
    except LwbenchError as exc:
        _fail(str(exc))
    where = summary.files[0] if format == "bag" else out
    console.print(f"decoded {summary.frames} frame(s) of {summary.codec}, {summary.points:,} points -> "
                  f"{escape(str(where))}")


DEFAULT_STREAM_CODECS = ("raw", "gmm", "vsgp")  # the VSGP paper's Fig. 6d


@app.command()
def stream(
    dataset: Annotated[str | None, typer.Option(help="Dataset name or path. Default: sim (the tunnel).")] = None,
    dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE for the dataset.")] = [],  # noqa: B006
    codec: Annotated[list[str], typer.Option("--codec", help="Codec to stream (repeat). Default: raw, gmm, vsgp.")]
    = [],  # noqa: B006
    param: Annotated[list[str], typer.Option("--param", help="CODEC.KEY=VALUE[,VALUE...] for a codec.")] = [],  # noqa: B006
    cap: Annotated[list[str], typer.Option("--cap", help="Link cap in KB/s (repeat; 'none' = no cap).")] = [],  # noqa: B006
    frames: Annotated[int, typer.Option(help="Scans to stream (at the sensor's rate).", min=1)] = 40,
    burst: Annotated[int | None, typer.Option(help="Token bucket size, bytes (default 100 ms of the cap).")] = None,
    loss: Annotated[float, typer.Option(help="Probability that a packet is lost.")] = 0.0,
    delay_ms: Annotated[float, typer.Option(help="One-way link delay, ms.")] = 0.0,
    corrupt: Annotated[float, typer.Option(help="Probability that a frame has a bit flipped on the wire.")] = 0.0,
    mtu: Annotated[int, typer.Option(help="Packet size, bytes.")] = 1400,
    queue: Annotated[int, typer.Option(help="Frames the scout keeps waiting for the link (keep last N).", min=1)]
    = 5,
    drain: Annotated[float, typer.Option(help="Seconds the link may go on after the last scan.")] = 2.0,
    restart_base_at: Annotated[
        float | None, typer.Option(help="Kill the base this many seconds in and start a new one (fault).")
    ] = None,
    threads: Annotated[int, typer.Option(help="torch/OpenMP threads per process.", min=1)] = 1,
    encode: Annotated[str, typer.Option(
        help="live: the scout encodes each scan as it is due; ahead: encoded and timed before the clock starts, "
             "each payload ready its measured encode time after its turn (the scout's encoding never overlaps "
             "the base's decoding)")] = "live",
    voxel: Annotated[float, typer.Option(help="Occupancy voxel (m) of the base's map.")] = 0.2,
    seed: Annotated[int, typer.Option(help="Seed of codecs, dataset and link faults.")] = 0,
    out: Annotated[Path, typer.Option(help="Folder for stream.json and the Fig. 6d plots.")] = Path("lwbench-stream"),
) -> None:
    """Stream a sequence from a scout process to a base process over 127.0.0.1 through a bandwidth cap:
    per codec KB/s, bytes, frames on time / late / dropped, latency and the base's map IoU; Fig. 6d."""
    from lwbench.link import LinkModel, StreamSettings, fig6d, parse_cap, ratio_line, run_study, table_rows
    from lwbench.run import parse_assignments, parse_sweeps, resolve_dataset
    from lwbench.run.plan import expand_codec_configs

    reg = _registry()
    try:
        names = list(dict.fromkeys(codec)) or list(DEFAULT_STREAM_CODECS)
        sweeps = parse_sweeps(param, names, "--param")
        configs = [c for n in names for c in expand_codec_configs(reg.codec(n), sweeps.get(n, {}), seed)]
        given = parse_assignments(dataset_param, "--dataset-param")
        spec = resolve_dataset(reg, dataset, given, seed)
        if any(p.name == "frames" for p in reg.dataset(spec.name).params) and "frames" not in given:
            spec = type(spec)(spec.name, {**spec.params, "frames": frames})  # the simulator: as many as streamed
        links = [LinkModel(parse_cap(c), burst, loss, delay_ms, corrupt, mtu, seed) for c in (cap or ["50"])]
        settings = StreamSettings(frames=frames, queue=queue, drain_s=drain, threads=threads, voxel=voxel,
                                  restart_at=restart_base_at, encode=encode)
        console.print(f"[bold]lwbench stream[/]: {escape(spec.label)} · {frames} scans · "
                      f"{len(configs)} codec(s) x {len(links)} link(s), one stream at a time")
        result = run_study(
            reg, spec, configs, links, settings,
            on_start=lambda c, link: console.print(f"  streaming {escape(c.name)} through {escape(link.label)} ..."),
        )
    except LwbenchError as exc:
        _fail(str(exc))
    out.mkdir(parents=True, exist_ok=True)
    (out / "stream.json").write_text(result.to_json())
    header, rows = table_rows(result.runs)
    table = Table(title=f"Streams at {result.rate_hz:g} Hz (on time = decoded before the next scan is due)",
                  title_justify="left")
    for i, h in enumerate(header):
        table.add_column(h, justify="left" if i < 2 else "right")
    for r in rows:
        table.add_row(*(escape(c) for c in r))
    console.print(table)
    line = ratio_line(result.runs)
    if line:
        console.print(escape(line))
    for link in dict.fromkeys(r.link for r in result.runs):
        name = "fig6d_" + ("uncapped" if link.rate_kbps is None else f"{link.rate_kbps:g}KBps")
        runs = [r for r in result.runs if r.link == link]
        paths = fig6d(runs, out, name, f"{result.dataset}: scout -> base, {link.label}")
        console.print(f"wrote {escape(str(paths[0]))} (+ .svg)")
    console.print(f"wrote {escape(str(out / 'stream.json'))}")


@app.command()
def view(
    source: Annotated[str, typer.Argument(help="The original: a scan file, dataset folder, ROS bag or dataset name.")],
    decoded: Annotated[
        Path | None, typer.Argument(help="A decoded cloud (.pcd/.ply), a payload or stream file. Else --codec.")
    ] = None,
    codec: Annotated[str | None, typer.Option(help="Encode and decode the frame with this codec (as a run).")] = None,
    param: Annotated[list[str], typer.Option("--param", help="KEY=VALUE for the codec.")] = [],  # noqa: B006
    dataset_param: Annotated[list[str], typer.Option("--dataset-param", help="KEY=VALUE for the dataset.")] = [],  # noqa: B006
    frame: Annotated[int, typer.Option(help="Which frame of the source (and of a stream file).", min=0)] = 0,
    png: Annotated[Path | None, typer.Option(help="Write this PNG instead of opening a window.")] = None,
    max_error: Annotated[float | None, typer.Option(help="Top of the colour scale, m (default: p95).")] = None,
    seed: Annotated[int, typer.Option(help="Seed, as lwbench run --seed.")] = 0,
) -> None:
    """Show an original scan beside its decoded cloud, coloured by error: Open3D's viewer where a
    display exists, else (headless) a PNG."""
    from lwbench.transcode import codec_config
    from lwbench.view import has_display, pair_from_codec, pair_from_file, render_png, show_window

    if (decoded is None) == (codec is None):
        _fail("give a decoded file or --codec (one of them)")
    reg = _registry()
    try:
        _, ds = _dataset(reg, source, dataset_param, seed)
        if frame >= len(ds):
            _fail(f"--frame {frame}: the source has {len(ds)} frame(s)")
        original = ds[frame]
        if decoded is not None:
            if not decoded.exists():
                _fail(f"{decoded} does not exist")
            pair = pair_from_file(reg, original, decoded, frame if decoded.suffix != ".lwb" else 0)
        else:
            pair = pair_from_codec(reg, original, codec_config(reg, codec, param, seed))
        if png is None and has_display():
            show_window(pair, max_error)
            return
        path = render_png(pair, png or Path("lwbench-view.png"), max_error)
    except LwbenchError as exc:
        _fail(str(exc))
    why = "" if png is not None else " (no display here)"
    console.print(f"wrote {escape(str(path))}{why}: {escape(pair.title)}")


# --------------------------------------------------------------------------------- simulate
@app.command()
def simulate(
    scene: Annotated[str, typer.Argument(help="Scene: tunnel, urban or indoor.")],
    out: Annotated[Path, typer.Option(help="Output folder (KITTI odometry layout).")],
    frames: Annotated[int | None, typer.Option(help="Number of scans.", min=1)] = None,
    seed: Annotated[int, typer.Option(help="Scene and noise seed.")] = 0,
    sensor: Annotated[str | None, typer.Option(help="Sensor preset (default: the scene's).")] = None,
) -> None:
    """Write a simulated sequence to disk in KITTI layout (readable by lwbench and other tools).

    The simulator is the default dataset (the installed dataset that declares ``is_default``)."""
    from lwbench.io import write_kitti_sequence

    reg = _registry()
    try:
        params: dict[str, object] = {"scene": scene, "seed": seed}
        if frames is not None:
            params["frames"] = frames
        if sensor is not None:
            params["sensor"] = sensor
        from lwbench.run import resolve_dataset

        spec = resolve_dataset(reg, None, params, seed)
        ds = spec.build(reg)
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


def _plugin_commands() -> None:
    """Commands that plugins add (hook ``lwbench_register_commands``); a plugin whose hook
    raises is reported like any plugin that fails to load, and the others still work."""
    reg = get_registry()
    for impl in reg.pm.hook.lwbench_register_commands.get_hookimpls():
        try:
            impl.function(cli=app)
        except Exception as exc:  # noqa: BLE001 - one plugin's bug must not take the CLI down
            reg._fail(impl.plugin_name, "lwbench_register_commands", exc)


_plugin_commands()


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
