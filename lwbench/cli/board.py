"""Reading results: ``lwbench leaderboard``, ``lwbench rd`` and ``lwbench report``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from lwbench.errors import LwbenchError, ParameterError, StoreError

from .app import app, registry
from .options import OUTPUT, RESULTS, ColumnsOpt, FormatOpt, MinCoverage, ShownDataset, SortOpt
from .output import console, escape, print_board, wanted_columns, writable_folder
from .running import BENCHMARK, board_sort


def _store(store: Path | None, first: str = "run `lwbench run` first") -> Path:
    from lwbench.run.request import DEFAULT_STORE

    path = store or DEFAULT_STORE
    if not path.exists():
        raise StoreError(f"no results store at {path} ({first})")
    return path


#: ``--store`` of the commands that read results: repeatable, a store or a bundle each.
SourcesOpt = Annotated[list[Path] | None, typer.Option(
    "--store", help="Results store or bundle (.jsonl[.gz], `lwbench export`); repeat to put several machines' "
    "results on one board.  [default: lwbench-results/results.sqlite]", show_default=False, rich_help_panel=RESULTS)]
ByMachine = Annotated[bool, typer.Option(
    "--by-machine", help="One line per machine (default: a configuration's rows pool: quality once per key, "
    "runtimes of every machine; the *_x columns compare machines).", rich_help_panel=OUTPUT)]


def _sources(paths: list[Path] | None, first: str = "run `lwbench run` first") -> list[Path]:
    """The stores and bundles a reading command was given (each checked to exist)."""
    from lwbench.results.bundle import is_bundle

    out = []
    for path in paths or [None]:
        out.append(path if path is not None and is_bundle(path) and path.exists() else _store(path, first))
    return out


def board_info_of(results, reg):
    """The metric declarations a board of ``results`` reads: the store's own, then the installed
    metrics' (:func:`lwbench.results.leaderboard.board_info`)."""
    from lwbench.results.leaderboard import board_info

    return board_info(results, reg.metric_declarations())


def _choice(value: str, choices: tuple[str, ...], option: str) -> None:
    if value not in choices:
        raise ParameterError(f"{option} must be {', '.join(choices[:-1])} or {choices[-1]}, got {value!r}")


@app.command(rich_help_panel=BENCHMARK)
def leaderboard(
    store: SourcesOpt = None,
    dataset: ShownDataset = None,
    sort: SortOpt = None,
    format: FormatOpt = "table",
    columns: ColumnsOpt = None,
    min_coverage: MinCoverage = None,
    by_machine: ByMachine = False,
    suite: Annotated[str | None, typer.Option(
        help="Only the rows a suite asked for: a name (any version) or an identity NAME+HASH "
             "(`lwbench suite list`).", rich_help_panel=RESULTS)] = None,
) -> None:
    """Aggregate stored rows (mean, std, median, p95 per codec configuration)."""
    from lwbench.results.bundle import open_results
    from lwbench.results.leaderboard import build_leaderboard, present_columns, to_csv, to_json, to_markdown

    _choice(format, ("table", "md", "csv", "json"), "--format")
    paths = _sources(store)
    path = ", ".join(map(str, paths))
    reg = registry()
    board = {} if min_coverage is None else {"min_coverage": min_coverage}
    with open_results(paths) as results:
        info = board_info_of(results, reg)
        keys = None
        if suite is not None:
            keys = {k for k, names in results.suites_of().items()
                    if any(n == suite or n.split("+")[0] == suite for n in names)}
            if not keys:
                raise LwbenchError(f"no rows of suite {suite!r} in {path}")
        entries = build_leaderboard(results, dataset=dataset, sort=sort, info=info, by_machine=by_machine,
                                    keys=keys, **board)
    stored_ids = {m for e in entries for m in e.stats}
    wanted = wanted_columns(columns, {**dict.fromkeys(stored_ids), **info})
    if not entries:
        raise LwbenchError("no results" + (f" for dataset {dataset!r}" if dataset else "") + f" in {path}")
    if format == "json":
        print(to_json(entries))
    elif format == "csv":
        print(to_csv(entries), end="")
    elif format == "md":
        cols = wanted or present_columns(entries, reg.default_columns())
        print(to_markdown(entries, cols, info), end="")
    else:
        print_board(entries, sort or board_sort(info), wanted, info)


@app.command(rich_help_panel=BENCHMARK)
def rd(
    distortion: Annotated[str | None, typer.Option(
        help="Distortion metric id (range_rmsd, chamfer, d1_psnr, ate_rmse, ...). Default: the range error.",
        rich_help_panel=OUTPUT)] = None,
    rate: Annotated[str | None, typer.Option(
        help="Rate metric id: bytes (per frame) or bits_per_point. Default: bytes per frame.",
        rich_help_panel=OUTPUT)] = None,
    store: SourcesOpt = None,
    dataset: ShownDataset = None,
    reference: Annotated[str | None, typer.Option(
        help="Codec the BD-rate / BD-distortion are measured against.", rich_help_panel=OUTPUT)] = None,
    at_rate: Annotated[float | None, typer.Option(
        help="Report each curve's distortion at this rate.", rich_help_panel=OUTPUT)] = None,
    at_distortion: Annotated[float | None, typer.Option(
        help="Report each curve's rate at this distortion.", rich_help_panel=OUTPUT)] = None,
    format: Annotated[str, typer.Option("--format", help="table | json", rich_help_panel=OUTPUT)] = "table",
    min_coverage: MinCoverage = None,
) -> None:
    """Rate-distortion from the sweep points in the store: each codec's curve, the Pareto front,
    values at equal rate / distortion (interpolated, never extrapolated) and BD-rate."""
    from lwbench.results.bundle import open_results
    from lwbench.results.leaderboard import build_leaderboard, check_metric_ids
    from lwbench.results.rd import curves_from_entries, default_axes, summarise

    _choice(format, ("table", "json"), "--format")
    reg = registry()
    # A curve needs a sweep, which a run file declares: plain `lwbench run` gives one point a codec.
    paths = _sources(store, "run a sweep first: `lwbench run --config examples/runs/rd_tunnel.toml`, "
                            "or a run file of your own with sweeps")
    path = ", ".join(map(str, paths))
    limits = {} if min_coverage is None else {"min_coverage": min_coverage}
    with open_results(paths) as results:
        info = board_info_of(results, reg)  # the store's declarations: the same axes wherever it is read
        default_distortion, default_rate = default_axes(info)
        distortion, rate = distortion or default_distortion, rate or default_rate
        check_metric_ids([distortion, rate], info, "lwbench rd")
        entries = build_leaderboard(results, dataset=dataset, info=info, **limits)
    if reference is not None and reference not in {e.codec for e in entries}:
        shown = ", ".join(sorted({e.codec for e in entries})) or "none"
        raise ParameterError(f"--reference {reference!r}: no such codec in {path} (stored: {shown})")
    left_out: list = []
    curves = curves_from_entries(entries, distortion, rate=rate, info=info, left_out=left_out, limits=limits)
    summary = summarise(curves, unit=info[distortion].unit, at_rate=at_rate, at_distortion=at_distortion,
                        reference=reference, left_out=left_out, rate_unit=info[rate].unit)
    if not summary:
        raise LwbenchError(f"no unflagged configuration in {path} has both {rate} and {distortion}")
    skipped = [{"dataset": e.dataset, "label": e.label, "reason": why} for e, why in left_out]
    if format == "json":
        print(json.dumps({"rate": rate, "distortion": distortion, "datasets": summary, "left_out": skipped}, indent=2))
        return
    _print_rd(summary, info, distortion, rate, reference, at_rate, at_distortion)
    from lwbench.noise_floor import print_floor  # the noise floor's line (docs/codecs.md)

    print_floor(entries, curves, info, lambda line: console.print(escape(line), highlight=False))
    if skipped:
        console.print("left out: " + escape("; ".join(f"{s['label']} ({s['reason']})" for s in skipped)))


def _print_rd(summary: dict, info, distortion: str, rate: str, reference: str | None, at_rate: float | None,
              at_distortion: float | None) -> None:
    from rich.table import Table

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
            parts = [bd["error"]] if "error" in bd else [
                f"BD-rate {bd['bd_rate_pct']:+.1f} %" if "bd_rate_pct" in bd else f"no BD-rate: {bd['bd_rate_error']}",
                f"BD-distortion {bd['bd_distortion']:+.3g} dB" if "bd_distortion" in bd
                else f"no BD-distortion: {bd['bd_distortion_error']}",
            ]
            console.print(f"BD vs {escape(str(reference))}: {escape(codec)}: {escape(', '.join(parts))}")


@app.command(rich_help_panel=BENCHMARK)
def report(
    out: Annotated[Path, typer.Option(
        help="Folder for index.html and the plots (PNG + SVG).", rich_help_panel=OUTPUT)] = Path("lwbench-report"),
    store: SourcesOpt = None,
    dataset: ShownDataset = None,
    config: Annotated[Path | None, typer.Option(
        help="Run this TOML study first (cached rows are reused), then report it.", rich_help_panel=RESULTS)] = None,
) -> None:
    """Write a self-contained HTML report: sortable leaderboard, RD curves, runtime, a gallery."""
    from lwbench.results.report import write_report

    writable_folder(out)
    reg = registry()
    if config is not None:
        from lwbench.run import Study
        from lwbench.run.config import read_run_file

        from .output import progress
        from .running import RunConsole

        if store and len(store) > 1:
            raise ParameterError("--config runs into one store: give one --store")
        request = read_run_file(config).with_options(store=store[0] if store else None)
        with progress() as shown:
            outcome = Study.prepare(request, reg).run(on_event=RunConsole(shown))
        done = [(s.evaluated, s.skipped, s.failed) for s in outcome.summaries]
        console.print(f"{escape(str(config))}: evaluated {sum(d[0] for d in done)}, cached {sum(d[1] for d in done)}, "
                      f"{sum(d[2] for d in done)} failure(s) -> {escape(str(request.store_path))}")
        if outcome.interrupted:
            raise typer.Exit(130)
        store = [request.store_path]
    page = write_report(_sources(store), out, reg, dataset=dataset)
    console.print(f"wrote {escape(str(page))} (open it in a browser; plots as PNG and SVG beside it)")
