"""``lwbench suite list`` and ``lwbench suite run NAME``: the benchmark protocols lwbench ships
(:mod:`lwbench.suites`), run exactly as pinned, every row tagged with the suite's identity."""

from __future__ import annotations

from typing import Annotated

import typer

from .app import app, registry
from .options import DatasetOpt, DatasetParams, StoreOpt, words
from .output import console, err_console, escape, print_board, progress
from .running import BENCHMARK, RunConsole, board_sort

suite_app = typer.Typer(help="Named, versioned benchmark protocols: the same study on every machine.",
                        no_args_is_help=True)
app.add_typer(suite_app, name="suite", rich_help_panel=BENCHMARK)


@suite_app.command("list")
def list_() -> None:
    """The suites this lwbench ships: name, identity (version + content hash), what each runs."""
    from rich.table import Table

    from lwbench.suites import list_suites

    table = Table("suite", "identity", "what it runs", title="Suites (lwbench suite run NAME)", title_justify="left")
    for s in list_suites():
        table.add_row(s.name, s.id, escape(s.description))
    console.print(table)


@suite_app.command("run")
def run(
    name: Annotated[str, typer.Argument(help="A suite's name (`lwbench suite list`), e.g. sim-tunnel-1.")],
    store: StoreOpt = None,
    dataset: DatasetOpt = None,
    dataset_param: DatasetParams = None,
    workers: Annotated[int, typer.Option(help="Parallel worker processes.", min=1)] = 1,
    machine: Annotated[str | None, typer.Option(
        help="Label the rows' machine (default: LWBENCH_MACHINE, else this host's description).")] = None,
    show_file: Annotated[bool, typer.Option("--show", help="Print the suite's run file and stop.")] = False,
) -> None:
    """Run a suite as pinned (cached rows are reused and tagged too), then print its board.
    ``--dataset PATH``: the suite's codecs and settings on your own data."""
    from dataclasses import replace

    from lwbench.results.leaderboard import board_info, build_leaderboard
    from lwbench.results.store import ResultStore
    from lwbench.run import Study, parse_assignments
    from lwbench.suites import find_suite

    suite = find_suite(name)
    if show_file:
        console.print(suite.path.read_text(), highlight=False, markup=False)
        return
    reg = registry()
    request = suite.request(dataset, parse_assignments(words(dataset_param), "--dataset-param"))
    request = replace(request, workers=max(workers, request.workers), machine=machine,
                      **({"store": store} if store is not None else {}))
    study = Study.prepare(request, reg)
    console.print(f"[bold]suite[/] {escape(suite.id)} -> {escape(str(request.store_path))}")
    with ResultStore(request.store_path) as results, progress() as shown:
        outcome = study.run(results, RunConsole(shown, request.store_path))
        if outcome.interrupted:
            err_console.print("[yellow]interrupted:[/] finished rows are stored; run the same command again to resume")
            raise typer.Exit(130)
        info = board_info(results, reg.metric_declarations())
        sort = board_sort(info)
        entries = build_leaderboard(results, sort=sort, info=info, keys=outcome.keys)
    print_board(entries, sort, None, info)

