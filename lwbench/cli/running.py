"""``lwbench run``: fill a :class:`~lwbench.run.RunRequest` from the options (or a run file), run
the :class:`~lwbench.run.Study`, print the board of what it asked for."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated

import typer

from lwbench.errors import ParameterError

from .app import app, registry
from .options import (
    DATA,
    EXECUTION,
    METRICS,
    CodecNames,
    ColumnsOpt,
    DatasetOpt,
    DatasetParams,
    Frames,
    MinCoverage,
    Seed,
    SortOpt,
    StoreOpt,
    Sweeps,
    words,
)
from .output import console, err_console, escape, print_board, progress, wanted_columns

BENCHMARK = "Benchmark"
#: lwbench.run.DEFAULT_TIMEOUT_S, written out: importing lwbench.run here would slow every command's start.
DEFAULT_TIMEOUT_S = 3600.0


@app.command(rich_help_panel=BENCHMARK)
def run(
    dataset: DatasetOpt = None,
    dataset_param: DatasetParams = None,
    codec: CodecNames = None,
    param: Sweeps = None,
    frames: Frames = None,
    store: StoreOpt = None,
    workers: Annotated[int, typer.Option(
        help="Parallel worker processes (frames in parallel).", min=1, rich_help_panel=EXECUTION)] = 1,
    seed: Seed = 0,
    # Only the negative flag (the metrics are on by default): a --x/--no-x pair is wider than typer's
    # option column at 80 columns, where rich cut it to "--no-sequence-met…".
    no_sequence_metrics: Annotated[bool, typer.Option(
        "--no-sequence-metrics", help="Skip the localization and occupancy metrics (run when the dataset has poses).",
        rich_help_panel=METRICS)] = False,
    metric: Annotated[list[str] | None, typer.Option(
        "--metric", help="Also run this opt-in sequence metric, e.g. kiss (repeat; `lwbench list` marks them).",
        rich_help_panel=METRICS)] = None,
    retry_failed: Annotated[bool, typer.Option(help="Re-evaluate stored failures.", rich_help_panel=EXECUTION)] = False,
    force: Annotated[bool, typer.Option(
        "--force", help="Recompute every row, even those already stored.", rich_help_panel=EXECUTION)] = False,
    metric_param: Annotated[list[str] | None, typer.Option(
        "--metric-param", help="METRIC.KEY=VALUE: a metric's setting, part of each row's key "
        "(geometry.peak: the PSNR peak, m).",
        rich_help_panel=METRICS)] = None,
    sort: SortOpt = None,
    columns: ColumnsOpt = None,
    min_coverage: MinCoverage = None,
    config: Annotated[Path | None, typer.Option(
        help="A TOML run file: datasets x codecs x grids x seeds (see docs).", rich_help_panel=DATA)] = None,
    isolate: Annotated[bool, typer.Option(
        "--isolate/--in-process", rich_help_panel=EXECUTION,
        help="Evaluate in worker processes with a timeout and a memory ceiling (default).")] = True,
    # None: not given -- a run file's timeout then holds, and DEFAULT_TIMEOUT_S where neither says.
    timeout: Annotated[float | None, typer.Option(
        help=f"Seconds one evaluation may take before its worker is killed (0: no limit; default: "
        f"{DEFAULT_TIMEOUT_S:g}, or a --config file's timeout).", min=0,
        rich_help_panel=EXECUTION)] = None,
    memory_limit: Annotated[int | None, typer.Option(
        help="MB of memory per worker (default: 80% of the machine's, shared).", min=1,
        rich_help_panel=EXECUTION)] = None,
    executor: Annotated[str, typer.Option(
        help="local, or ray: evaluations as Ray tasks (lwbench\\[ray]).", rich_help_panel=EXECUTION)] = "local",
    address: Annotated[str | None, typer.Option(
        help="Ray cluster address (--executor ray; default: start a local Ray).", rich_help_panel=EXECUTION)] = None,
    machine: Annotated[str | None, typer.Option(
        help="Label the rows' machine (a team or host name on a common board; default: LWBENCH_MACHINE, else "
             "this host's description).", rich_help_panel=EXECUTION)] = None,
) -> None:
    """Evaluate codecs on a dataset; every result lands in the store; print the leaderboard."""
    from lwbench.results.leaderboard import build_leaderboard, check_metric_ids
    from lwbench.results.store import ResultStore
    from lwbench.run import RunRequest, Study
    from lwbench.run.config import read_run_file

    reg = registry()
    options = {"retry_failed": retry_failed, "force": force, "isolate": isolate, "memory_mb": memory_limit,
               "executor": executor, "address": address, "machine": machine}
    if config is not None:
        if dataset or dataset_param or codec or param:
            raise ParameterError("--config describes the datasets and codecs: leave out --dataset, --codec and --param")
        request = read_run_file(config)
        request = request.with_options(store=store, workers=max(workers, request.workers),
                                       metrics=tuple(words(metric)) or None, **options)
        if timeout is not None:  # given on the command line: it wins over the file's (0 too: no limit)
            request = replace(request, timeout_s=timeout or None)
    else:
        request = RunRequest.from_words(
            reg, dataset=dataset, dataset_params=words(dataset_param), codecs=words(codec), params=words(param),
            metric_params=words(metric_param), seed=seed, frames=frames, sequence_metrics=not no_sequence_metrics,
            metrics=tuple(words(metric)), store=store, workers=workers,
            timeout_s=(DEFAULT_TIMEOUT_S if timeout is None else timeout) or None, **options)
    from lwbench.results.leaderboard import board_info

    info = board_info(None, reg.metric_declarations())  # the installed metrics' (+ runtimes as *_x)
    wanted = wanted_columns(columns, info)
    if sort is not None:
        check_metric_ids([sort], info, "--sort")  # before the evaluation, not after it
    study = Study.prepare(request, reg)
    with ResultStore(request.store_path) as results, progress() as shown:
        outcome = study.run(results, RunConsole(shown, request.store_path))
        if outcome.interrupted:
            err_console.print("[yellow]interrupted:[/] finished rows are stored; run the same command again to resume")
            raise typer.Exit(130)
        info = board_info(results, reg.metric_declarations())
        sort = sort or board_sort(info)
        board = {} if min_coverage is None else {"min_coverage": min_coverage}
        entries = build_leaderboard(results, sort=sort, info=info, keys=outcome.keys, **board)
    if len(study.plans) == 1:
        console.print(f"dataset: {escape(study.plans[0].dataset.label)}")
    print_board(entries, sort, wanted, info)


def board_sort(info) -> str:
    """The metric a board is sorted by when ``--sort`` is not given."""
    from lwbench.results.leaderboard import headline_metric

    return headline_metric(info)


class RunConsole:
    """A study's events on the terminal: each plan announced, its phases as progress bars
    (:class:`RunProgress`), its counts and first failures when it ends."""

    def __init__(self, shown, store: Path | None = None) -> None:
        self.shown, self.store = shown, store
        self.phases: RunProgress | None = None
        self.total = 0

    def __call__(self, event) -> None:
        from lwbench.run import PlanFinished, PlanStarted

        if isinstance(event, PlanStarted):
            if self.store is not None:
                console.print(
                    f"[bold]lwbench run[/]: {escape(event.plan.dataset.label)} · {event.frames} frame(s) · "
                    f"{event.configs} codec configuration(s) · store {escape(str(self.store))}")
            if event.sequence_skipped:
                err_console.print(f"[yellow]note:[/] {escape(event.sequence_skipped)}", highlight=False)
            self.total = event.frames * event.configs
            self.phases = RunProgress(self.shown, event.has_sequence_stage)
        elif isinstance(event, PlanFinished):
            if self.phases is not None:
                self.phases.close()
            s = event.summary
            if self.store is not None:
                console.print(
                    f"evaluated {s.evaluated}, cached {s.skipped} of {self.total}; "
                    f"{s.failed} failure(s); {s.sequence_rows} sequence row(s)")
                for f in s.failures[:10]:
                    err_console.print(f"[red]failed:[/] {escape(f)}", highlight=False)
        elif self.phases is not None:
            self.phases(event)


class RunProgress:
    """A plan's progress events as phases: the frames (encode, decode and frame metrics of every
    codec; a simulated dataset's scans are simulated here too, frame by frame), then the sequence
    metrics. The frames phase is open from the start, so that a long first frame (a simulation,
    a worker starting) is already reported."""

    def __init__(self, shown, has_sequence_stage: bool) -> None:
        self.shown, self.has_sequence_stage = shown, has_sequence_stage
        self.frames = shown.phase("frames (encode, decode, frame metrics)", announce=False)
        self.sequence = None

    def __call__(self, event) -> None:
        row = event.row
        if event.phase == "frames":
            self.frames.update(event.done, total=event.total, what=f"last: {row.codec} frame {row.frame}",
                               part=row.codec)
            if event.done >= event.total and self.has_sequence_stage:
                self._sequence_phase()
            return
        phase = self._sequence_phase()
        if row is None:  # inside a task: which configuration, metric, pass and frame
            phase.update(event.done, total=event.total, what=event.what)
            return
        phase.update(event.done, total=event.total, what=f"last: {row.codec} · {row.part}", part=row.codec)

    def _sequence_phase(self):
        if self.sequence is None:
            self.frames.finish()
            self.sequence = self.shown.phase("sequence metrics")
        return self.sequence

    def close(self) -> None:
        """The plan is over: its open phase ends (a later plan opens its own)."""
        (self.sequence or self.frames).finish()
