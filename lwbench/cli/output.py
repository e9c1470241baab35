"""What the commands print: two consoles, one error line, progress bars and the leaderboard table."""

from __future__ import annotations

import sys

from rich.console import Console
from rich.markup import escape

__all__ = ["console", "err_console", "escape", "print_board", "print_error", "progress_bar", "wanted_columns"]

# Off a terminal (CI logs, pipes) rich would wrap tables at 80 columns; leaderboards are wide.
console = Console(width=None if sys.stdout.isatty() else 200)
err_console = Console(stderr=True, soft_wrap=True)


def print_error(message: str) -> None:
    """The one line a user error gets (escaped: ``pip install 'lwbench[ray]'`` is not markup)."""
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False)


def progress_bar(*, eta: bool = False):
    """A progress bar on a terminal (nothing when stdout is a pipe or a file)."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = [TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn()]
    if eta:
        columns += [TextColumn("eta"), TimeRemainingColumn()]
    return Progress(*columns, console=console, transient=False, disable=not sys.stdout.isatty())


def wanted_columns(columns: str | None, available) -> tuple[str, ...] | None:
    """``--columns a,b``: the ids, each checked (``None``: the default columns)."""
    from lwbench.leaderboard import check_metric_ids

    if not columns:
        return None
    wanted = tuple(c.strip() for c in columns.split(",") if c.strip())
    check_metric_ids(list(wanted), available, "--columns")
    return wanted


def print_board(entries, sort: str, wanted: tuple[str, ...] | None, info) -> None:
    """The board in the terminal (:mod:`lwbench.board_table`): never folds a number -- columns
    that do not fit are left out (and named), so read a wide board with --columns or --format md."""
    from lwbench.board_table import board_columns, board_table, flag_notes

    table, dropped = board_table(entries, board_columns(entries, sort, info, wanted), info, sort=sort,
                                 width=console.width or 200)
    console.print(table)
    if dropped:
        names = escape(", ".join(dropped))
        console.print(f"[dim]not shown (terminal too narrow): {names}; use --columns or --format md[/]")
    for note in flag_notes(entries):
        console.print(f"[dim]{escape(note)}[/]")
    for e in entries:
        for err in e.errors:
            err_console.print(f"[red]{escape(e.label)}[/]: {escape(err)}", highlight=False)
        if e.stale:
            err_console.print(f"[dim]{escape(e.label)}: {e.stale} older row(s) scored another way are not included[/]")
