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
DEFAULT_STREAM_CODECS = ("raw", "gmm", "vsgp")  # the VSGP paper's Fig. 6d


@app.command(rich_help_panel=PANEL)
def stream(
    dataset: DatasetOpt = None,
    dataset_param: DatasetParams = None,
    codec: Annotated[list[str] | None, typer.Option(
        "--codec", help="Codec to stream (repeat). Default: raw, gmm, vsgp.", rich_help_panel=CODECS)] = None,
    param: Sweeps = None,
    cap: Annotated[list[str] | None, typer.Option(
        "--cap", help="Link cap in KB/s (repeat; 'none' = no cap). Default: 50.", rich_help_panel=LINK)] = None,
    frames: Annotated[int, typer.Option(
        "--frames", min=1, rich_help_panel=DATA,
        help="Only the first N frames of the dataset, streamed at the sensor's rate (the simulator is asked for at "
             "least N).")] = 40,
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
    from lwbench.link import LinkModel, StreamSettings, fig6d, parse_cap, ratio_line, run_study
    from lwbench.run import frames_for, parse_assignments, parse_sweeps, resolve_dataset
    from lwbench.run.plan import expand_codec_configs

    writable_folder(out)  # before the study: an unwritable --out must not cost the whole stream
    reg = registry()
    names = list(dict.fromkeys(words(codec))) or list(DEFAULT_STREAM_CODECS)
    sweeps = parse_sweeps(words(param), names, "--param")
    configs = [c for n in names for c in expand_codec_configs(reg.codec(n), sweeps.get(n, {}), seed)]
    spec = resolve_dataset(reg, dataset, parse_assignments(words(dataset_param), "--dataset-param"), seed)
    spec = frames_for(reg, spec, frames)
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
    line = ratio_line(result.runs)
    if line:
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
