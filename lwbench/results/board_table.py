"""The leaderboard in a terminal: the default columns, narrow headers, and a table that fits.

The board exists for its task metrics, and the main job's board (``lwbench run`` on the
simulator) used to print ``not shown (terminal too narrow): ate_rmse, occ_iou`` even at ~190
columns. Three things make the default board fit 120 columns with every default column in it:

- **the default columns** are what the metrics declare ``default`` (the compression rate, the
  range and geometry distortions with coverage, encode and decode time, the task metrics);
  ``select_ms`` is part of ``encode_ms`` and ``false_returns`` / ``d1_psnr`` are behind
  ``--columns``;
- **narrow headers**: the unit goes on a second header line, and an id that ends in its unit
  says it once (``encode_ms`` [ms] is headed ``encode`` over ``ms``); the ``fail`` column shows
  only when some configuration failed (its rows are flagged ``failed rows`` too);
- **a light table**: a rule under the header and two spaces between columns, no box.

Narrower than that, columns are left out -- never a number folded -- and named under the table:
runtimes first, then ids with no role, rates, guarded ids, and the distortions last (the board's
order puts the task metrics, which declare the highest ``order``, at its right end, so among the
distortions the leftmost goes first); the sort column is never left out. Headers and the order
come from what each metric declares (:class:`lwbench.MetricId`): no metric is known by name.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from lwbench.metric import MetricId
from lwbench.results.leaderboard import FLAG_NOTES, LeaderboardEntry, present_columns, short_dataset_labels, table_rows

__all__ = ["board_columns", "board_table", "board_title", "flag_notes", "short_header"]

# Units a reader needs; shares, counts and the ratio are plain numbers (as leaderboard.header_name).
_PLAIN_UNITS = ("", "share", "pts", "frames", "x")
# Which columns a narrow terminal leaves out first (lower first): by what the metric declares.
# A rate beside the headline ratio says the same thing in other units, so it goes before a guarded id.
_RUNTIME, _PLAIN, _RATE, _GUARDED, _DISTORTION = range(5)


def short_header(metric: str, info: Mapping[str, MetricId] | None) -> str:
    """A metric's header on a narrow board: the id over its unit (``range_rmsd`` / ``m``); an id
    that ends in its unit says it once (``encode_ms`` -> ``encode`` / ``ms``). Two lines always,
    so every id stands on the first."""
    unit = getattr((info or {}).get(metric), "unit", "")
    if unit in _PLAIN_UNITS:
        return f"{metric}\n"
    suffix = f"_{unit.lower()}"
    name = metric[: -len(suffix)] if metric.lower().endswith(suffix) and len(metric) > len(suffix) else metric
    return f"{name}\n{unit}"


def board_columns(
    entries: Sequence[LeaderboardEntry], sort: str, info: Mapping[str, MetricId], wanted: tuple[str, ...] | None
) -> tuple[str, ...]:
    """``wanted`` (``--columns``), else the declared default columns some entry has a value for,
    with the sort column in front when it is not one of them."""
    if wanted is not None:
        return wanted
    cols = present_columns(list(entries), tuple(i for i, m in info.items() if m.default))
    if sort and sort not in cols and any(e.value(sort) is not None for e in entries):
        cols = (sort, *cols)
    return cols


def board_title(sort: str) -> str:
    return f"Leaderboard (mean over frames; sorted by {sort}, rows with a quality flag last)"


def _priority(metric: str, info: Mapping[str, MetricId]) -> int:
    m = info.get(metric)
    role = getattr(m, "role", "")
    if role == "runtime":
        return _RUNTIME
    if role == "rate":
        return _RATE
    if role == "distortion":
        return _DISTORTION
    return _GUARDED if getattr(m, "guard", None) is not None else _PLAIN


def _leave_out_order(columns: Sequence[str], info: Mapping[str, MetricId], sort: str) -> list[str]:
    """The columns a narrow terminal leaves out, first first (the sort column never)."""
    where = {c: i for i, c in enumerate(columns)}

    def key(c: str) -> tuple[int, int]:
        p = _priority(c, info)
        return (p, where[c] if p == _DISTORTION else -where[c])

    return sorted((c for c in columns if c != sort), key=key)


def _table(
    entries: Sequence[LeaderboardEntry], columns: Sequence[str], info: Mapping[str, MetricId], title: str
) -> Table:
    short, _ = short_dataset_labels(e.dataset for e in entries)
    header, rows = table_rows(list(entries), tuple(columns), info, name=short_header, fail_column=False,
                              dataset_label=short)
    text = header.index("frames")  # dataset, codec: text; frames, fail and the metrics: numbers
    flags = len(header) - 1 if header[-1] == "flags" else None
    table = Table(
        title=escape(title), title_justify="left", box=box.SIMPLE_HEAD, show_edge=False, collapse_padding=True
    )
    for i, h in enumerate(header):
        numeric = i >= text and i != flags
        label = h if "\n" in h else f"{h}\n"  # every name on the first header line
        table.add_column(escape(label), justify="right" if numeric else "left", no_wrap=numeric)
    for r in rows:
        table.add_row(*(escape(c) for c in r))
    return table


def table_width(table: Table) -> int:
    """The columns ``table`` takes when nothing is folded (its natural width)."""
    console = Console(file=io.StringIO(), width=100_000)
    return console.measure(table).maximum


def board_table(
    entries: Sequence[LeaderboardEntry],
    columns: Sequence[str],
    info: Mapping[str, MetricId],
    *,
    sort: str,
    width: int,
) -> tuple[Table, list[str]]:
    """The board as a rich table no wider than ``width``, and the ids left out to get there (in
    the board's order); a number is never folded."""
    keep = list(columns)
    dropped: list[str] = []
    while True:
        table = _table(entries, keep, info, board_title(sort))
        victims = _leave_out_order(keep, info, sort)
        if table_width(table) <= width or not victims:
            return table, [c for c in columns if c in dropped]
        keep.remove(victims[0])
        dropped.append(victims[0])


def flag_notes(entries: Sequence[LeaderboardEntry]) -> list[str]:
    """What each board flag shown means, once (a guard's flag explains itself)."""
    shown = {f for e in entries for f in e.flags}
    return [note for flag, note in FLAG_NOTES.items() if flag in shown]
