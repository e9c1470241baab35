"""``lwbench export`` and ``lwbench import``: a store's rows as a portable bundle, and bundles
from other machines into a store (:mod:`lwbench.results.bundle`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from lwbench.errors import ParameterError

from .app import app
from .options import ShownDataset, StoreOpt
from .output import console, escape
from .running import BENCHMARK


@app.command("export", rich_help_panel=BENCHMARK)
def export(
    out: Annotated[Path, typer.Argument(help="The bundle to write: NAME.jsonl, or NAME.jsonl.gz (compressed).")],
    store: StoreOpt = None,
    dataset: ShownDataset = None,
) -> None:
    """Write a store's rows as one portable bundle (JSON lines: provenance, machine, versions,
    suite and the metric declarations they were scored with; no decoded clouds)."""
    from lwbench.results.bundle import export_bundle, is_bundle
    from lwbench.results.store import ResultStore

    from .board import _store

    if not is_bundle(out):
        raise ParameterError(f"{out}: a bundle's name ends in .jsonl or .jsonl.gz")
    if not out.parent.is_dir():
        raise ParameterError(f"{out}: the folder {out.parent} does not exist")
    path = _store(store)
    with ResultStore(path, readonly=True) as results:
        n = export_bundle(results, out, dataset=dataset)
    console.print(f"wrote {n} row(s) of {escape(str(path))} to {escape(str(out))}")


@app.command("import", rich_help_panel=BENCHMARK)
def import_(
    bundles: Annotated[list[Path], typer.Argument(help="Bundles written by `lwbench export` (on any machine).")],
    store: StoreOpt = None,
) -> None:
    """Add other machines' bundles to a store: their rows show on its board, report and rd
    beside this machine's (one row per machine and configuration; never taken as this machine's
    cache). Every bundle is checked whole before anything is written."""
    from lwbench.results.bundle import import_bundle, read_bundle
    from lwbench.results.store import ResultStore
    from lwbench.run.request import DEFAULT_STORE

    for bundle in bundles:  # all checked first: a damaged third bundle must not leave two imported
        read_bundle(bundle)
    path = store or DEFAULT_STORE
    with ResultStore(path) as results:
        for bundle in bundles:
            n = import_bundle(bundle, results)
            console.print(f"imported {n} row(s) from {escape(str(bundle))} into {escape(str(path))}")

