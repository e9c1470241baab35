"""Payloads and clouds on disk: ``lwbench encode``, ``decode`` and ``view`` (and the dataset words
every command that reads data shares)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lwbench.errors import DataFormatError, ParameterError

from .app import app, registry
from .options import OUTPUT, CodecName, CodecSettings, DatasetArg, DatasetParams, Frames, Seed, words
from .output import console, escape, progress, writable_folder

PANEL = "Files"


def open_source(reg, source: str | None, dataset_param: list[str] | None, seed: int, frames: int | None = None):
    """A dataset from a registered name or a path, as ``lwbench run --dataset`` resolves it, with
    ``--frames`` meaning what it means everywhere: ``(spec, dataset)``."""
    from lwbench.run import frames_for, parse_assignments, resolve_dataset

    spec = resolve_dataset(reg, source, parse_assignments(words(dataset_param), "--dataset-param"), seed)
    spec = frames_for(reg, spec, frames)
    return spec, spec.build(reg)


@app.command(rich_help_panel=PANEL)
def encode(
    source: DatasetArg,
    codec: CodecName,
    out: Annotated[Path, typer.Option(help="Output folder.", rich_help_panel=OUTPUT)],
    param: CodecSettings = None,
    dataset_param: DatasetParams = None,
    frames: Frames = None,
    seed: Seed = 0,
    stream: Annotated[bool, typer.Option(
        "--stream", help="One .lwbs stream file instead of one .lwb per frame.", rich_help_panel=OUTPUT)] = False,
) -> None:
    """Write payloads: one .lwb per frame plus stream.json (codec, parameters, sensor table, index), or
    one .lwbs stream file; the bytes are what lwbench run measures and what crosses the link."""
    from lwbench.transcode import codec_config, encode_dataset

    writable_folder(out)
    reg = registry()
    config = codec_config(reg, codec, words(param), seed)
    spec, ds = open_source(reg, source, dataset_param, seed, frames)
    with progress() as shown, shown.phase(f"encoding with {config.label}") as phase:
        summary = encode_dataset(reg, ds, config, out, stream=stream, frames=frames, source=spec.label,
                                 on_frame=lambda done, n: phase.update(done, total=n))
    ratio = summary.raw_bytes / summary.payload_bytes if summary.payload_bytes else float("nan")
    console.print(
        f"wrote {summary.frames} frame(s), {summary.payload_bytes:,} bytes ({ratio:.1f}x smaller than float32 "
        f"x,y,z) as a {summary.layout}: {escape(str(summary.path))}"
    )


@app.command(rich_help_panel=PANEL)
def decode(
    file: Annotated[Path, typer.Argument(help="A .lwbs stream file, a .lwb payload or a folder of them.")],
    out: Annotated[Path, typer.Option(
        help="Output folder (for --format bag: the new bag's folder).", rich_help_panel=OUTPUT)],
    format: Annotated[str, typer.Option("--format", help="pcd | ply | bag (ROS 2)", rich_help_panel=OUTPUT)] = "pcd",
    param: CodecSettings = None,
    storage: Annotated[str, typer.Option(help="Bag storage: mcap or sqlite3 (.db3).", rich_help_panel=OUTPUT)]
    = "mcap",
) -> None:
    """Decode payloads into clouds named after their source frames (NAME.CODEC.pcd, with sensor.json and
    poses.txt beside them), or into a ROS 2 bag on the source's topics and stamps."""
    from lwbench.streamfile import open_payloads
    from lwbench.transcode import decode_payloads

    if not file.exists():
        raise DataFormatError(f"{file} does not exist")
    # A bag's folder must not exist yet (the bag writer makes it): check the folder it goes in.
    writable_folder(out.parent if format == "bag" else out, "--out" if format != "bag" else "--out's parent")
    summary = decode_payloads(registry(), open_payloads(file), out, fmt=format, overrides=words(param),
                              storage=storage)
    where = summary.files[0] if format == "bag" else out
    console.print(f"decoded {summary.frames} frame(s) of {summary.codec}, {summary.points:,} points -> "
                  f"{escape(str(where))}")


def _frame_named_by(ds, decoded: Path | None) -> int:
    """The frame a decoded file belongs to, by name: ``lwbench decode`` names each cloud after its
    scan (``000010.bin`` -> ``000010.vsgp.pcd``). A one-frame source, a codec run or a stream file
    means frame 0; a decoded file of a longer source whose name is no scan's is refused -- compared
    with the wrong scan, its errors would be the distance between two scans (issue 33)."""
    if decoded is None or len(ds) == 1 or decoded.suffix == ".lwbs":
        return 0
    stem = decoded.name.split(".")[0]
    for i in range(len(ds)):
        if ds.frame_origin(i).get("name") == stem:
            return i
    raise ParameterError(f"{decoded.name} is named after no scan of the source ({len(ds)} frames): pass --frame N")


@app.command(rich_help_panel=PANEL)
def view(
    source: Annotated[str, typer.Argument(help="The original: a scan file, dataset folder, ROS bag or dataset name.")],
    decoded: Annotated[Path | None, typer.Argument(
        help="A decoded cloud (.pcd/.ply), a payload or stream file. Else --codec.")] = None,
    codec: Annotated[str | None, typer.Option(
        help="Encode and decode the frame with this codec (as a run).", rich_help_panel="Codecs")] = None,
    param: CodecSettings = None,
    dataset_param: DatasetParams = None,
    frame: Annotated[int | None, typer.Option(
        help="Which frame of the source (and of a stream file). Default: the scan a decoded file is "
             "named after (000010.vsgp.pcd: 000010), else the first.", min=0, rich_help_panel="Data")] = None,
    png: Annotated[Path | None, typer.Option(
        help="Write this PNG instead of opening a window.", rich_help_panel=OUTPUT)] = None,
    max_error: Annotated[float | None, typer.Option(
        help="Top of the colour scale, m (default: p95).", rich_help_panel=OUTPUT)] = None,
    seed: Seed = 0,
) -> None:
    """Show an original scan beside its decoded cloud, coloured by error: Open3D's viewer where a
    display exists, else (headless) a PNG."""
    from lwbench.transcode import codec_config
    from lwbench.view import has_display, pair_from_codec, pair_from_file, render_png, show_window

    if (decoded is None) == (codec is None):
        raise ParameterError("give a decoded file or --codec (one of them)")
    reg = registry()
    _, ds = open_source(reg, source, dataset_param, seed)
    if frame is None:
        frame = _frame_named_by(ds, decoded)
    if frame >= len(ds):
        raise ParameterError(f"--frame {frame}: the source has {len(ds)} frame(s)")
    original = ds[frame]
    if decoded is not None:
        if not decoded.exists():
            raise DataFormatError(f"{decoded} does not exist")
        pair = pair_from_file(reg, original, decoded, frame if decoded.suffix != ".lwb" else 0)
    else:
        pair = pair_from_codec(reg, original, codec_config(reg, codec, words(param), seed))
    if png is None and has_display():
        show_window(pair, max_error)
        return
    path = render_png(pair, png or Path("lwbench-view.png"), max_error)
    why = "" if png is not None else " (no display here)"
    console.print(f"wrote {escape(str(path))}{why}: {escape(pair.title)}")
