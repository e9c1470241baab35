"""``lwbench simulate``: a simulated sequence written in KITTI layout."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .app import app, registry
from .files import PANEL, open_source
from .options import DATA, OUTPUT, Frames
from .output import console, escape, progress, writable_folder


@app.command(rich_help_panel=PANEL)
def simulate(
    scene: Annotated[str, typer.Argument(help="Scene: tunnel, urban, indoor or town.")],
    out: Annotated[Path, typer.Option(help="Output folder (KITTI odometry layout).", rich_help_panel=OUTPUT)],
    frames: Frames = None,
    seed: Annotated[int, typer.Option(help="Scene and noise seed.", rich_help_panel=DATA)] = 0,
    sensor: Annotated[str | None, typer.Option(
        help="Sensor preset (default: the scene's).", rich_help_panel=DATA)] = None,
) -> None:
    """Write a simulated sequence to disk in KITTI layout (readable by lwbench and other tools).

    The simulator is the default dataset (the installed dataset that declares ``is_default``)."""
    from lwbench.io import write_kitti_sequence

    writable_folder(out)
    reg = registry()
    words = [f"scene={scene}", f"seed={seed}", *([f"sensor={sensor}"] if sensor is not None else [])]
    _, ds = open_source(reg, None, words, seed, frames)
    n = min(len(ds), frames) if frames else len(ds)
    with progress() as shown:
        with shown.phase(f"simulating {scene}", n) as phase:

            def scans():
                for i in range(n):  # each scan written as it is cast, none kept
                    phase.update(what=f"scan {i}")
                    yield ds[i]
                    phase.advance()

            write_kitti_sequence(scans(), out)
    console.print(f"wrote {n} scans of {scene!r} to {escape(str(out))} (run: lwbench run --dataset {out})")
