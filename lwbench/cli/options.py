"""Options shared by several commands, declared once: each word means one thing on every command.

``--frames N`` is always *the first N frames of the dataset* (a dataset that generates its frames,
the simulator, is asked for at least N); ``--param`` is a codec sweep (``CODEC.KEY=V1,V2``) where a
command runs several configurations and one codec's settings (``KEY=VALUE``) where it runs one;
``--dataset`` names what to read (a registered dataset or a path) where a command reads data, and
what to show (a name, label or id in the store) where it reads results.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = [
    "CODECS", "DATA", "EXECUTION", "METRICS", "OUTPUT", "RESULTS",
    "CodecName", "CodecNames", "CodecSettings", "DatasetArg", "DatasetOpt", "DatasetParams", "Frames",
    "FormatOpt", "MinCoverage", "Seed", "ShownDataset", "SortOpt", "StoreOpt", "Sweeps", "ColumnsOpt",
]

# rich_help_panel groups: a command's --help lists its options under these headings.
DATA = "Data"
CODECS = "Codecs"
METRICS = "Metrics"
EXECUTION = "Execution"
RESULTS = "Results"
OUTPUT = "Output"

DatasetOpt = Annotated[str | None, typer.Option(
    "--dataset", help="Registered dataset name or a path (auto-detected). Default: sim.", rich_help_panel=DATA)]
DatasetArg = Annotated[str, typer.Argument(help="A scan file, dataset folder, ROS bag or dataset name (sim).")]
DatasetParams = Annotated[list[str] | None, typer.Option(
    "--dataset-param", help="KEY=VALUE for the dataset (repeat).", rich_help_panel=DATA)]
Frames = Annotated[int | None, typer.Option(
    "--frames", min=1, rich_help_panel=DATA,
    help="Only the first N frames of the dataset (the simulator is asked for at least N).")]
Seed = Annotated[int, typer.Option(help="Seed of every codec and dataset that declares one.", rich_help_panel=DATA)]

CodecNames = Annotated[list[str] | None, typer.Option(
    "--codec", help="Codec to run (repeat). Default: the main set.", rich_help_panel=CODECS)]
CodecName = Annotated[str, typer.Option("--codec", help="The codec.", rich_help_panel=CODECS)]
Sweeps = Annotated[list[str] | None, typer.Option(
    "--param", help="CODEC.KEY=V1[,V2...]: a codec's parameter values (several: a sweep).", rich_help_panel=CODECS)]
CodecSettings = Annotated[list[str] | None, typer.Option(
    "--param", help="KEY=VALUE (or CODEC.KEY=VALUE): a setting of the codec (repeat).", rich_help_panel=CODECS)]

StoreOpt = Annotated[Path | None, typer.Option(
    "--store", help="SQLite results store.  [default: lwbench-results/results.sqlite]", show_default=False,
    rich_help_panel=RESULTS)]
ShownDataset = Annotated[str | None, typer.Option(
    "--dataset", help="Only this dataset (name, label or id).", rich_help_panel=RESULTS)]
SortOpt = Annotated[str | None, typer.Option(
    "--sort", help="Metric id to sort by (default: the board's headline metric, ratio).", rich_help_panel=OUTPUT)]
ColumnsOpt = Annotated[str | None, typer.Option(
    "--columns", help="Comma-separated metric ids to show.", rich_help_panel=OUTPUT)]
MinCoverage = Annotated[float | None, typer.Option(
    "--min-coverage", min=0, max=1, rich_help_panel=OUTPUT,
    help="Flag configurations whose coverage is below this.  [default: 0.9]", show_default=False)]
FormatOpt = Annotated[str, typer.Option("--format", help="table | md | csv | json", rich_help_panel=OUTPUT)]


def words(items: list[str] | None) -> list[str]:
    """A repeatable option's values (typer gives ``None`` when it was not given)."""
    return list(items or [])
