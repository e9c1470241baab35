"""``lwbench stream``: scout -> base over a real, capped link (the VSGP paper's Fig. 6d)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .app import app, registry
from .options import CODECS, DATA, OUTPUT, DatasetOpt, DatasetParams, Sweeps, words
from .output import console, escape, progress, writable_folder

PANEL = "Link"
LINK = "Link model"
DEFAULT_FRAMES = 40


@app.command(rich_help_panel=PANEL)
def stream(
    dataset: DatasetOpt = None,
    dataset_param: DatasetParams = None,
    codec: Annotated[list[str] | None, typer.Option(
        "--codec", help="Codec to stream (repeat; the first is the reference of the byte ratios). Default: the "
        "codecs of a default run.", rich_help_panel=CODECS)] = None,
    param: Sweeps = None,
    cap: Annotated[list[str] | None, typer.Option(
        "--cap", help="Link cap in KB/s (repeat; 'none' = no cap). Default: 50.", rich_help_panel=LINK)] = None,
    frames: Annotated[int | None, typer.Option(
        "--frames", min=1, rich_help_panel=DATA,
        help="Only the first N frames of the dataset, streamed at the sensor's rate (the simulator is asked for at "
             f"least N). Default: the run file's, else {DEFAULT_FRAMES}.")] = None,
    config: Annotated[Path | None, typer.Option(
        help="A TOML run file naming the dataset and the codecs with their settings (one dataset, one seed), e.g. "
             "examples/runs/fig6d.toml: the VSGP paper's Fig. 6d.", rich_help_panel=DATA)] = None,
    burst: Annotated[int | None, typer.Option(
        help="Token bucket size, bytes (default 100 ms of the cap).", rich_help_panel=LINK)] = None,
    loss: Annotated[float, typer.Option(help="Probability that a packet is lost.", rich_help_panel=LINK)] = 0.0,
    delay_ms: Annotated[float, typer.Option(help="One-way link delay, ms.", rich_help_panel=LINK)] = 0.0,
    corrupt: Annotated[float, typer.Option(
        help="Probability that a frame has a bit flipped on the wire.", rich_help_panel=LINK)] = 0.0,
    mtu: Annotated[int, typer.Option(help="Packet size, bytes.", rich_help_panel=LINK)] = 1400,
    queue: Annotated[int, typer.Option(
        help="Frames the scout keeps waiting for the link (keep last N).", min=1, rich_help_panel=LINK)] = 5,
    drain: Annotated[float, typer.Option(
        help="Seconds the link may go on after the last scan.", rich_help_panel=LINK)] = 2.0,
    restart_base_at: Annotated[float | None, typer.Option(
        help="Kill the base this many seconds in and start a new one (fault).", rich_help_panel=LINK)] = None,
    threads: Annotated[int, typer.Option(help="torch/OpenMP threads per process.", min=1)] = 1,
    encode: Annotated[str, typer.Option(
        help="live: the scout encodes each scan as it is due; ahead: encoded and timed before the clock starts, "
             "each payload ready its measured encode time after its turn (the scout's encoding never overlaps "
             "the base's decoding)")] = "live",
    voxel: Annotated[float, typer.Option(help="Occupancy voxel (m) of the base's map.")] = 0.2,
    seed: Annotated[int, typer.Option(help="Seed of codecs, dataset and link faults.", rich_help_panel=DATA)] = 0,
    out: Annotated[Path, typer.Option(
        help="Folder for stream.json and the Fig. 6d plots.", rich_help_panel=OUTPUT)] = Path("lwbench-stream"),
) -> None:
    """Stream a sequence from a scout process to a base process over 127.0.0.1 through a bandwidth cap:
    per codec KB/s, bytes, frames on time / late / dropped, latency and the base's map IoU; Fig. 6d."""
    from lwbench.errors import ParameterError
    from lwbench.link import LinkModel, StreamSettings, fig6d, parse_cap, ratio_lines, run_study
    from lwbench.run import RunRequest

    writable_folder(out)  # before the study: an unwritable --out must not cost the whole stream
    reg = registry()
    if config is not None:
        from lwbench.run.config import read_run_file

        if dataset or dataset_param or codec or param:
            raise ParameterError("--config names the dataset and the codecs: leave out --dataset, --codec and --param")
        request = read_run_file(config)
        if len(request.datasets) != 1 or len(request.seeds) != 1:
            raise ParameterError(f"{config}: a stream runs one dataset with one seed (the file has "
                                 f"{len(request.datasets)} dataset(s), {len(request.seeds)} seed(s))")
        if frames is None:
            frames = request.datasets[0].frames or request.frames
        seed = request.seeds[0]
    else:
        request = RunRequest.from_words(reg, dataset=dataset, dataset_params=words(dataset_param),
                                        codecs=words(codec), params=words(param), seed=seed)
    frames = frames or DEFAULT_FRAMES
    # The same planning as `lwbench run` (every name and value checked), for the stream's frames.
    (plan,) = RunRequest(datasets=request.datasets, codecs=request.codecs, sweeps=request.sweeps, frames=frames,
                         seeds=(seed,)).plans(reg)
    configs, spec = list(plan.configs), plan.dataset
    links = [LinkModel(parse_cap(c), burst, loss, delay_ms, corrupt, mtu, seed) for c in (words(cap) or ["50"])]
    settings = StreamSettings(frames=frames, queue=queue, drain_s=drain, threads=threads, voxel=voxel,
                              restart_at=restart_base_at, encode=encode)
    console.print(f"[bold]lwbench stream[/]: {escape(spec.label)} · {frames} scans · "
                  f"{len(configs)} codec(s) x {len(links)} link(s), one stream at a time")
    with progress() as shown:
        reading = shown.phase(f"reading the {frames} scans of {spec.label}", frames)
        streams: list = []

        def on_start(config, link) -> None:  # one phase per stream: its heartbeat says it is alive
            for phase in (reading, *streams):
                phase.finish()
            streams.append(shown.phase(f"streaming {config.name} through {link.label}", frames))

        result = run_study(reg, spec, configs, links, settings, on_start=on_start,
                           on_frame=lambda done, n: reading.update(done, total=n),
                           on_scan=lambda done, n: streams[-1].update(done, total=n))
    (out / "stream.json").write_text(result.to_json())
    for table in stream_tables(result.runs, result.rate_hz):
        console.print(table)
    for line in ratio_lines(result.runs):
        console.print(escape(line))
    for link in dict.fromkeys(r.link for r in result.runs):
        name = "fig6d_" + ("uncapped" if link.rate_kbps is None else f"{link.rate_kbps:g}KBps")
        runs = [r for r in result.runs if r.link == link]
        paths = fig6d(runs, out, name, f"{result.dataset}: scout -> base, {link.label}")
        console.print(f"wrote {escape(str(paths[0]))} (+ .svg)")
    console.print(f"wrote {escape(str(out / 'stream.json'))}")


def stream_tables(runs, rate_hz: float) -> list:
    """The stream table as rich tables (:data:`lwbench.link.STREAM_TABLES`): a value folds onto
    a second line of its cell rather than being cut."""
    from rich.table import Table

    from lwbench.link import STREAM_TABLES, table_rows

    header, rows = table_rows(runs)
    tables = []
    for what, columns in STREAM_TABLES:
        table = Table(title=f"Streams at {rate_hz:g} Hz: {what} (on time = decoded before the next scan is due)",
                      title_justify="left")
        at = [header.index(c) for c in columns]
        for i, c in enumerate(columns):
            table.add_column(c, justify="left" if i < 2 else "right", overflow="fold")
        for r in rows:
            table.add_row(*(escape(r[i]) for i in at))
        tables.append(table)
    return tables
