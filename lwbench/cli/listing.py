"""``lwbench list`` (what is installed) and ``lwbench inspect`` (what a file holds)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from lwbench.errors import DataFormatError

from .app import app, registry
from .output import console

PANEL = "Plugins and files"


def installed(reg) -> dict:
    """Codecs, datasets and metrics with their parameters and providers, and the failed plugins."""
    from lwbench.metric import as_metric_id

    return {
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
                "in_default_run": getattr(m, "in_default_run", True),
            }
            for kind, table in (("frame", reg.frame_metrics), ("sequence", reg.sequence_metrics))
            for n, m in sorted(table.items())
        ],
        "failures": [{"plugin": f.plugin, "target": f.target, "error": f.error} for f in reg.failures],
    }


def _params_text(params: list[dict]) -> str:
    return ", ".join(
        f"{p['name']}={p['default']}"
        + (f" {p['range']}" if "range" in p else "")
        + (f" {{{'|'.join(p['choices'])}}}" if "choices" in p else "")
        for p in params
    )


@app.command("list", rich_help_panel=PANEL)
def list_plugins(
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable output.")] = False,
) -> None:
    """Codecs, datasets and metrics with their parameters and the package providing each."""
    data = installed(registry())
    if as_json:
        print(json.dumps(data, indent=2, default=str))
        return
    for title, items in (("Codecs", data["codecs"]), ("Datasets", data["datasets"])):
        table = Table(title=title, title_justify="left")
        for col in ("name", "kind" if title == "Codecs" else "description", "parameters", "provider"):
            table.add_column(col)
        for it in items:
            kind = it.get("kind", it["description"])
            if it.get("unavailable"):
                kind = f"{kind} [red](unavailable: {escape(it['unavailable'])})[/red]"
            table.add_row(it["name"], kind, _params_text(it["params"]), it["provider"])
        console.print(table)
    table = Table(title="Metrics", title_justify="left")
    for col in ("name", "kind", "ids", "provider"):
        table.add_column(col)
    for m in data["metrics"]:
        kind = m["kind"] if m["in_default_run"] else f"{m['kind']} (opt-in: --metric {m['name']})"
        table.add_row(m["name"], kind, ", ".join(m["ids"]), m["provider"])
    console.print(table)
    if data["failures"]:
        table = Table(title="Plugins that failed to load", title_justify="left", style="red")
        for col in ("plugin", "target", "error"):
            table.add_column(col)
        for f in data["failures"]:
            table.add_row(f["plugin"], f["target"], f["error"])
        console.print(table)


@app.command(rich_help_panel=PANEL)
def inspect(
    file: Annotated[Path, typer.Argument(help="A payload, stream file, scan, dataset folder, bag or store.")],
) -> None:
    """Say what a file holds: an lwbench payload or stream file, a scan, a dataset folder, a ROS bag or a
    results store."""
    from lwbench.inspection import describe

    if not file.exists():
        raise DataFormatError(f"{file} does not exist")
    info = describe(file, registry())
    table = Table(title=str(file), title_justify="left", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value", overflow="fold")
    for k, v in info.items():
        table.add_row(k, v if isinstance(v, str) else json.dumps(v, default=str))
    console.print(table)
