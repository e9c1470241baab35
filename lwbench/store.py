"""The results store: one SQLite row per (dataset, frame, codec, parameters) evaluation.

SQLite in WAL mode with one transaction per row, so a killed run loses at most the row being
computed, readers (``lwbench leaderboard``) never block the writer, and a re-run skips every
key already stored. Each row carries its provenance -- lwbench, plugin and library versions,
machine, seed -- because a number nobody can reproduce is worth little.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import sqlite3
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

__all__ = ["ResultStore", "ResultRow", "result_key", "environment_versions"]

SCHEMA_VERSION = 1
_SCHEMA = """
CREATE TABLE IF NOT EXISTS results (
    key             TEXT PRIMARY KEY,
    kind            TEXT NOT NULL CHECK (kind IN ('frame', 'sequence')),
    dataset         TEXT NOT NULL,
    dataset_id      TEXT NOT NULL,
    frame           INTEGER NOT NULL,
    codec           TEXT NOT NULL,
    codec_version   TEXT NOT NULL,
    params          TEXT NOT NULL,
    status          TEXT NOT NULL CHECK (status IN ('ok', 'failed')),
    error           TEXT,
    metrics         TEXT NOT NULL,
    extra           TEXT NOT NULL,
    seed            INTEGER NOT NULL,
    lwbench_version TEXT NOT NULL,
    versions        TEXT NOT NULL,
    machine         TEXT NOT NULL,
    created         TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS results_by_config ON results (dataset_id, codec, params);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def result_key(
    kind: str, dataset_id: str, frame: int, codec: str, codec_version: str, params: dict, seed: int, part: str = ""
) -> str:
    """The identity of one evaluation: same inputs, same key, so a re-run is a cache hit."""
    blob = canonical_json([kind, dataset_id, frame, codec, codec_version, params, seed, part])
    return hashlib.sha256(blob.encode()).hexdigest()


def _json_safe(metrics: dict[str, float | None]) -> dict[str, float | str | None]:
    # JSON has no inf/NaN: infinities (lossless PSNR) are stored as strings, NaN as null.
    out: dict[str, float | str | None] = {}
    for k, v in metrics.items():
        if v is None or (isinstance(v, float) and math.isnan(v)):
            out[k] = None
        elif isinstance(v, float) and math.isinf(v):
            out[k] = "inf" if v > 0 else "-inf"
        else:
            out[k] = float(v)
    return out


def _from_json(metrics: dict) -> dict[str, float | None]:
    return {k: (float(v) if isinstance(v, str) else v) for k, v in metrics.items()}


@dataclass
class ResultRow:
    kind: str
    dataset: str
    dataset_id: str
    frame: int
    codec: str
    codec_version: str
    params: dict
    status: str
    metrics: dict[str, float | None]
    seed: int
    error: str | None = None
    extra: dict = field(default_factory=dict)
    part: str = ""
    versions: dict = field(default_factory=dict)
    lwbench_version: str = ""
    machine: str = ""
    created: str = ""

    @property
    def key(self) -> str:
        return result_key(
            self.kind, self.dataset_id, self.frame, self.codec, self.codec_version, self.params, self.seed, self.part
        )


def environment_versions(extra_modules: Iterable[str] = ()) -> dict[str, str]:
    """Versions of the libraries results depend on (imported lazily: only what is loaded)."""
    import importlib.metadata as md

    out = {"python": platform.python_version()}
    for dist in ("numpy", "scipy", "torch", "gpytorch", "open3d-cpu", "open3d", "DracoPy", *extra_modules):
        try:
            out[dist] = md.version(dist)
        except md.PackageNotFoundError:
            continue
    return out


def machine_description() -> str:
    import os

    return f"{platform.node()} {platform.machine()} {os.cpu_count()} cpu {platform.system()}"


class ResultStore:
    """Append-mostly SQLite store. Safe to read while a run writes (WAL)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.conn = sqlite3.connect(str(self.path), timeout=30.0)
        self.conn.execute("PRAGMA journal_mode=WAL")
        self.conn.execute("PRAGMA synchronous=NORMAL")
        with self.conn:
            self.conn.executescript(_SCHEMA)
            self.conn.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def has(self, key: str) -> bool:
        return self.conn.execute("SELECT 1 FROM results WHERE key = ?", (key,)).fetchone() is not None

    def status(self, key: str) -> str | None:
        row = self.conn.execute("SELECT status FROM results WHERE key = ?", (key,)).fetchone()
        return row[0] if row else None

    def put(self, row: ResultRow) -> None:
        """Insert or replace one row in its own transaction."""
        from lwbench import __version__

        created = row.created or datetime.now(timezone.utc).isoformat(timespec="seconds")
        extra = {**row.extra, "part": row.part} if row.part else row.extra
        with self.conn:
            self.conn.execute(
                "INSERT OR REPLACE INTO results VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (
                    row.key,
                    row.kind,
                    row.dataset,
                    row.dataset_id,
                    row.frame,
                    row.codec,
                    row.codec_version,
                    canonical_json(row.params),
                    row.status,
                    row.error,
                    json.dumps(_json_safe(row.metrics), sort_keys=True),
                    canonical_json(extra),
                    row.seed,
                    row.lwbench_version or __version__,
                    canonical_json(row.versions or environment_versions()),
                    row.machine or machine_description(),
                    created,
                ),
            )

    def rows(self, *, dataset: str | None = None, kind: str | None = None) -> Iterator[ResultRow]:
        sql = (
            "SELECT kind, dataset, dataset_id, frame, codec, codec_version, params, status, "
            "metrics, seed, error, extra, versions, lwbench_version, machine, created FROM results"
        )
        clauses, args = [], []
        if dataset is not None:
            clauses.append("(dataset = ? OR dataset_id = ? OR dataset LIKE ?)")
            args += [dataset, dataset, f"{dataset}%"]
        if kind is not None:
            clauses.append("kind = ?")
            args.append(kind)
        if clauses:
            sql += " WHERE " + " AND ".join(clauses)
        sql += " ORDER BY dataset, codec, params, frame"
        for r in self.conn.execute(sql, args):
            extra = json.loads(r[11])
            yield ResultRow(
                kind=r[0],
                dataset=r[1],
                dataset_id=r[2],
                frame=r[3],
                codec=r[4],
                codec_version=r[5],
                params=json.loads(r[6]),
                status=r[7],
                metrics=_from_json(json.loads(r[8])),
                seed=r[9],
                error=r[10],
                extra=extra,
                part=extra.get("part", ""),
                versions=json.loads(r[12]),
                lwbench_version=r[13],
                machine=r[14],
                created=r[15],
            )

    def count(self) -> int:
        return self.conn.execute("SELECT COUNT(*) FROM results").fetchone()[0]
