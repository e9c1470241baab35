"""Results in Python: ``lwbench.open_results(...)`` for notebooks and scripts.

::

    import lwbench
    with lwbench.open_results("lwbench-results/results.sqlite") as results:
        board = results.leaderboard_frame()          # a pandas DataFrame, one line per configuration
        rows = results.rows_frame()                  # one line per stored row (frame or sequence)
        best = board.sort_values("ratio", ascending=False).head()

The same stores and bundles ``lwbench leaderboard --store`` takes, several at once; the board is
built exactly as the command line builds it (the store's metric declarations, the guards, the
``*_x`` runtimes). pandas is optional (``pip install 'lwbench[pandas]'``): :meth:`Results.rows`
and :meth:`Results.leaderboard` give plain dicts without it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lwbench.errors import MissingDependencyError
from lwbench.results.bundle import open_results as _open_sources
from lwbench.results.leaderboard import board_info, build_leaderboard
from lwbench.results.store import ResultStore

__all__ = ["Results", "open_results"]


def _pandas():
    try:
        import pandas
    except ImportError:
        raise MissingDependencyError("tables need pandas: pip install 'lwbench[pandas]'") from None
    return pandas


class Results:
    """Stored results, read-only: rows and boards as dicts or DataFrames."""

    def __init__(self, store: ResultStore) -> None:
        self.store = store

    def __enter__(self) -> Results:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.store.close()

    def rows(self, dataset: str | None = None) -> list[dict[str, Any]]:
        """One dict per row: its identity (dataset, codec, params, frame, seed, machine, key),
        status and every metric value as a column."""
        suites = self.store.suites_of()
        out = []
        for r in self.store.rows(dataset=dataset):
            out.append({"dataset": r.dataset, "dataset_id": r.dataset_id, "kind": r.kind, "part": r.part,
                        "frame": r.frame, "codec": r.codec, "params": r.params, "seed": r.seed,
                        "machine": r.machine, "status": r.status, "error": r.error, "key": r.key,
                        "suites": suites.get(r.key, []), "reference_ms": r.extra.get("reference_ms"),
                        **r.metrics})
        return out

    def leaderboard(self, *, dataset: str | None = None, sort: str | None = None, by_machine: bool = False,
                    min_coverage: float | None = None) -> list[dict[str, Any]]:
        """The board ``lwbench leaderboard --format json`` prints: one dict per configuration."""
        from lwbench.registry import get_registry

        info = board_info(self.store, get_registry().metric_declarations())
        entries = build_leaderboard(self.store, dataset=dataset, sort=sort, info=info, by_machine=by_machine,
                                    min_coverage=min_coverage)
        return [e.as_dict() for e in entries]

    def rows_frame(self, dataset: str | None = None):
        """:meth:`rows` as a pandas DataFrame."""
        return _pandas().DataFrame(self.rows(dataset))

    def leaderboard_frame(self, **options: Any):
        """:meth:`leaderboard` as a pandas DataFrame (same order: best first per dataset)."""
        return _pandas().DataFrame(self.leaderboard(**options))


def open_results(*sources: str | Path) -> Results:
    """Results of one store, or of several stores and bundles together (a common board);
    default: the store ``lwbench run`` writes."""
    from lwbench.run.request import DEFAULT_STORE

    paths = [Path(s) for s in sources] or [DEFAULT_STORE]
    return Results(_open_sources(paths))
