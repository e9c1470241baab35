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
    """The board in the terminal: never folds a number -- columns that do not fit are left out
    (and named), so read a wide board with --columns or --format md."""
    from rich.table import Table

    from lwbench.leaderboard import present_columns, table_rows

    if wanted is None:
        cols = present_columns(entries, tuple(info_id for info_id, i in info.items() if i.default))
        if sort not in cols and any(e.value(sort) is not None for e in entries):
            cols = (sort, *cols)
    else:
        cols = wanted
    header, rows = table_rows(entries, cols, info)
    width = console.width or 200
    fixed = header.index("fail") + 1
    # What rich needs per column: the widest cell, one space of padding each side, one border.
    widths = [max(len(h), *(len(r[i]) for r in rows)) + 3 if rows else len(h) + 3 for i, h in enumerate(header)]
    dropped: list[str] = []
    keep = list(range(len(header)))
    flags_col = [len(header) - 1] if header[-1] == "flags" else []
    while sum(widths[i] for i in keep) + 1 > width and len(keep) > fixed + 1 + len(flags_col):
        victim = [i for i in keep if i >= fixed and i not in flags_col][-1]
        keep.remove(victim)
        dropped.append(header[victim])
    table = Table(title=f"Leaderboard (mean over frames; sorted by {escape(sort)})", title_justify="left")
    for i in keep:
        numeric = i >= fixed and i not in flags_col
        table.add_column(escape(header[i]), justify="right" if numeric else "left", no_wrap=numeric)
    for r in rows:
        table.add_row(*(escape(r[i]) for i in keep))
    console.print(table)
    if dropped:
        names = escape(", ".join(reversed(dropped)))
        console.print(f"[dim]not shown (terminal too narrow): {names}; use --columns or --format md[/]")
    for e in entries:
        for err in e.errors:
            err_console.print(f"[red]{escape(e.label)}[/]: {escape(err)}", highlight=False)
        if e.stale:
            err_console.print(f"[dim]{escape(e.label)}: {e.stale} older row(s) scored another way are not included[/]")
