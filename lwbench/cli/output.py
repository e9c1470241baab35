"""What the commands print: two consoles, one error line, progress bars and the leaderboard table."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from rich.console import Console
from rich.markup import escape

from lwbench.errors import ParameterError

__all__ = [
    "console", "err_console", "escape", "print_board", "print_error", "progress", "wanted_columns",
    "writable_folder",
]

# Off a terminal (CI logs, pipes) rich would wrap tables at 80 columns; leaderboards are wide.
console = Console(width=None if sys.stdout.isatty() else 200)
err_console = Console(stderr=True, soft_wrap=True)


def print_error(message: str) -> None:
    """The one line a user error gets (escaped: ``pip install 'lwbench[ray]'`` is not markup)."""
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False)


def writable_folder(path: Path, option: str = "--out") -> Path:
    """Create an output folder now and prove a file can be written in it -- before any work, so
    that an unwritable ``--out`` (``/proc/x``, a file, a read-only mount) costs no simulation,
    encoding or streaming. A real write, not ``os.access``: root passes every access check."""
    if path.exists() and not path.is_dir():
        raise ParameterError(f"{option} {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ParameterError(f"{option} {path}: cannot create the folder ({exc.strerror or exc})") from exc
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise ParameterError(f"{option} {path}: cannot write in the folder ({exc.strerror or exc})") from exc
    return path


def progress():
    """The phases of a long command: a bar on a terminal, plain lines on stderr elsewhere (see
    :mod:`lwbench.progress`)."""
    from lwbench.progress import Progress

    return Progress(console=err_console)


def wanted_columns(columns: str | None, available) -> tuple[str, ...] | None:
    """``--columns a,b``: the ids, each checked (``None``: the default columns)."""
    from lwbench.results.leaderboard import check_metric_ids

    if not columns:
        return None
    wanted = tuple(c.strip() for c in columns.split(","))
    if not all(wanted):
        raise ParameterError(f"--columns {columns!r}: an empty metric id (two commas, or one at an end)")
    check_metric_ids(list(wanted), available, "--columns")
    return wanted


def print_board(entries, sort: str, wanted: tuple[str, ...] | None, info) -> None:
    """The board in the terminal (:mod:`lwbench.results.board_table`): never folds a number -- columns
    that do not fit are left out (and named), so read a wide board with --columns or --format md."""
    from lwbench.results.board_table import board_columns, board_table, flag_notes
    from lwbench.results.leaderboard import short_dataset_labels

    table, dropped = board_table(entries, board_columns(entries, sort, info, wanted), info, sort=sort,
                                 width=console.width or 200)
    console.print(table)
    if dropped:
        names = escape(", ".join(dropped))
        console.print(f"[dim]not shown (terminal too narrow): {names}; use --columns or --format md[/]")
    _, common = short_dataset_labels(e.dataset for e in entries)
    if common and len({e.dataset for e in entries}) > 1:
        console.print(f"[dim]every dataset: {escape(', '.join(common))}[/]")
    for note in flag_notes(entries):
        console.print(f"[dim]{escape(note)}[/]")
    for e in entries:
        for err in e.errors:
            err_console.print(f"[red]{escape(e.label)}[/]: {escape(err)}", highlight=False)
        if e.stale:
            err_console.print(f"[dim]{escape(e.label)}: {e.stale} older row(s) scored another way are not included[/]")
