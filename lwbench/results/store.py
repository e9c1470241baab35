"""The results store: one SQLite row per (dataset, frame, codec, parameters) evaluation.

SQLite in WAL mode with one transaction per row, so a killed run loses at most the row being
computed, readers (``lwbench leaderboard``) never block the writer, and a re-run skips every
key already stored. Each row carries its provenance -- lwbench, plugin and library versions,
machine, seed -- because a number nobody can reproduce is worth little. The arrays a row keeps
(decoded clouds, the originals a report shows) are files beside the store, content-addressed
and compressed (:mod:`lwbench.results.artifacts`); the store holds their names.
"""

from __future__ import annotations

import json
import platform
import sqlite3
from collections.abc import Callable, Iterable, Iterator
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from lwbench.errors import StoreError
from lwbench.results.artifacts import CloudFiles, pack_array, unpack_array
from lwbench.results.rows import (
    ResultRow,
    canonical_json,
    evaluation_key,
    json_safe_metrics,
    metrics_from_json,
    result_key,
    row_from_dict,
    row_to_dict,
)
from lwbench.results.sqlite_files import (
    ask_sqlite,
    connect_readonly,
    connect_writable,
    empty_sqlite,
    schema_version,
    table_columns,
)

__all__ = ["ResultStore", "ResultRow", "evaluation_key", "result_key", "environment_versions", "is_results_store",
           "row_from_dict", "row_to_dict"]

# 2: rows carry the codec plugin's package version and the scoring signature (metric names,
#    versions, parameters and settings), both part of the key.
# 3: arrays are files beside the store (table artifact_files: their names); older stores' arrays
#    stay readable in the artifacts table.
# 4: rows say whether the dataset's sensor model was guessed (column sensor_guessed; rows of older
#    stores read as not guessed -- nobody recorded it then). An older lwbench refuses a schema-4
#    store rather than show its guessed rows without their flag.
# 5: the store carries its metrics' declarations (table metric_declarations: unit, direction,
#    headline, guard of each scoring metric), so a board ranks and flags the same wherever it is
#    read; rows imported from other machines' bundles (table imported, one row per machine and
#    key); which suite asked for which row (table suite_rows). An older lwbench would rank a
#    store without the metric plugin wrongly and miss the imported rows: it refuses schema 5.
SCHEMA_VERSION = 5
_COLUMNS = (
    "key", "kind", "dataset", "dataset_id", "frame", "codec", "codec_version", "params", "status", "error",
    "metrics", "extra", "seed", "lwbench_version", "versions", "machine", "created", "plugin_version", "scoring",
    "sensor_guessed",
)
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
    created         TEXT NOT NULL,
    plugin_version  TEXT NOT NULL DEFAULT '',
    scoring         TEXT NOT NULL DEFAULT '[]',
    sensor_guessed  INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS results_by_config ON results (dataset_id, codec, params);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS artifacts (
    evaluation      TEXT NOT NULL,
    name            TEXT NOT NULL,
    data            BLOB NOT NULL,
    PRIMARY KEY (evaluation, name)
);
CREATE TABLE IF NOT EXISTS artifact_files (
    evaluation      TEXT NOT NULL,
    name            TEXT NOT NULL,
    digest          TEXT NOT NULL,
    PRIMARY KEY (evaluation, name)
);
CREATE TABLE IF NOT EXISTS metric_declarations (
    name            TEXT NOT NULL,
    version         TEXT NOT NULL,
    declaration     TEXT NOT NULL,
    PRIMARY KEY (name, version)
);
CREATE TABLE IF NOT EXISTS imported (
    machine         TEXT NOT NULL,
    key             TEXT NOT NULL,
    row             TEXT NOT NULL,
    bundle          TEXT NOT NULL,
    PRIMARY KEY (machine, key)
);
CREATE TABLE IF NOT EXISTS suite_rows (
    suite           TEXT NOT NULL,
    key             TEXT NOT NULL,
    PRIMARY KEY (suite, key)
);
"""
# Columns added after schema 1, with the values old rows get.
_ADDED = {
    "plugin_version": "TEXT NOT NULL DEFAULT ''",
    "scoring": "TEXT NOT NULL DEFAULT '[]'",
    "sensor_guessed": "INTEGER NOT NULL DEFAULT 0",
}


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


#: The columns every results store has had since schema 1 (what recognises one).
_REQUIRED = tuple(c for c in _COLUMNS if c not in _ADDED)


def is_results_store(path: str | Path) -> bool:
    """Whether ``path`` is an lwbench results store (checked read-only: nothing is written)."""
    path = Path(path)
    return path.is_file() and ask_sqlite(path, lambda conn: schema_version(conn, _REQUIRED) is not None)



class ResultStore:
    """Append-mostly SQLite store. Safe to read while a run writes (WAL).

    ``readonly=True`` opens an existing store without writing a byte (``lwbench leaderboard``,
    ``inspect``, reports); otherwise the store is created if missing, and an existing file is
    written into only if it *is* a results store of a schema this lwbench knows (older schemas
    are migrated in place by adding columns; old rows keep their keys and simply stop being
    cache hits).
    """

    def __init__(self, path: str | Path, *, readonly: bool = False) -> None:
        self.path = Path(path)
        self.readonly = readonly
        if self.path.is_dir():
            raise StoreError(f"{self.path} is a directory, not a results store file")
        exists = self.path.is_file() and self.path.stat().st_size > 0
        if readonly and not exists:
            raise StoreError(f"no results store at {self.path}")
        if exists and not readonly and empty_sqlite(self.path):
            # Another run is creating this store at this moment (its tables are not committed
            # yet): two runs started together on a new store both initialise it, idempotently.
            exists = False
        if exists and not is_results_store(self.path):
            raise StoreError(
                f"{self.path} is not an lwbench results store"
                + (" (refusing to write into another file)" if not readonly else "")
            )
        try:
            if readonly:
                self.conn = connect_readonly(self.path)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.conn = connect_writable(self.path)
        except (sqlite3.Error, OSError) as exc:
            raise StoreError(f"cannot open results store {self.path}: {exc}") from None
        version = schema_version(self.conn, _REQUIRED) if exists else SCHEMA_VERSION
        if version is None or version > SCHEMA_VERSION:
            self.conn.close()
            raise StoreError(
                f"{self.path} has results store schema {version}, newer than this lwbench reads "
                f"({SCHEMA_VERSION}): upgrade lwbench"
            )
        if not readonly:
            try:
                with self.conn:
                    self.conn.executescript(_SCHEMA)
                    missing = {c: t for c, t in _ADDED.items() if c not in table_columns(self.conn, "results")}
                    for column, decl in missing.items():
                        self.conn.execute(f"ALTER TABLE results ADD COLUMN {column} {decl}")
                    self.conn.execute(
                        "INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
                    )
            except sqlite3.Error as exc:
                self.conn.close()
                raise StoreError(f"cannot write results store {self.path}: {exc}") from None
        self._present = table_columns(self.conn, "results")
        self._has_artifacts = bool(table_columns(self.conn, "artifacts"))
        self._has_files = bool(table_columns(self.conn, "artifact_files"))
        self._has_imported = bool(table_columns(self.conn, "imported"))
        self._has_declarations = bool(table_columns(self.conn, "metric_declarations"))
        self._has_suites = bool(table_columns(self.conn, "suite_rows"))
        # An in-memory store (a gate without a store) keeps its arrays in memory too.
        self.files = None if str(path) == ":memory:" else CloudFiles.beside(self.path)

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

    def put(self, row: ResultRow, artifacts: dict[str, np.ndarray] | None = None) -> None:
        """Insert or replace one row -- and the arrays it produced (``artifacts``, e.g. the
        decoded cloud, kept under the row's *evaluation* key) -- in one transaction (the arrays'
        files are written first, so a row never names a file that is not there)."""
        from lwbench.version import __version__

        if self.readonly:
            raise StoreError(f"{self.path} was opened read-only")
        created = row.created or datetime.now(timezone.utc).isoformat(timespec="seconds")
        extra = {**row.extra, "part": row.part} if row.part else row.extra
        values = {
            "key": row.key,
            "kind": row.kind,
            "dataset": row.dataset,
            "dataset_id": row.dataset_id,
            "frame": row.frame,
            "codec": row.codec,
            "codec_version": row.codec_version,
            "params": canonical_json(row.params),
            "status": row.status,
            "error": row.error,
            "metrics": json.dumps(json_safe_metrics(row.metrics), sort_keys=True),
            "extra": canonical_json(extra),
            "seed": row.seed,
            "lwbench_version": row.lwbench_version or __version__,
            "versions": canonical_json(row.versions or environment_versions()),
            "machine": row.machine or machine_description(),
            "created": created,
            "plugin_version": row.plugin_version,
            "scoring": canonical_json(row.scoring),
            "sensor_guessed": int(bool(row.sensor_guessed)),
        }
        kept = self._keep(row.evaluation, artifacts or {})
        with self.conn:
            self.conn.execute(
                f"INSERT OR REPLACE INTO results ({', '.join(_COLUMNS)}) VALUES ({', '.join('?' * len(_COLUMNS))})",
                [values[c] for c in _COLUMNS],
            )
            kept(self.conn)

    def put_artifact(self, key: str, name: str, array: np.ndarray) -> None:
        """Store an array that belongs to no single row (e.g. an original scan a report shows)."""
        if self.readonly:
            raise StoreError(f"{self.path} was opened read-only")
        kept = self._keep(key, {name: array})
        with self.conn:
            kept(self.conn)

    def _keep(self, key: str, arrays: dict[str, np.ndarray]) -> Callable[[sqlite3.Connection], None]:
        """Write the arrays' files now; return what records their names (inside the row's
        transaction). An in-memory store keeps the arrays themselves."""
        if self.files is None:
            blobs = [(key, name, pack_array(a)) for name, a in arrays.items()]
            return lambda conn: conn.executemany("INSERT OR REPLACE INTO artifacts VALUES (?, ?, ?)", blobs)
        names = [(key, name, self.files.put(a)) for name, a in arrays.items()]
        return lambda conn: conn.executemany("INSERT OR REPLACE INTO artifact_files VALUES (?, ?, ?)", names)

    def artifact(self, evaluation: str, name: str) -> np.ndarray | None:
        """An array kept with an evaluation (``None`` if it was not kept, or its file is gone):
        a file beside the store, or a blob in an in-memory store."""
        if self._has_files and self.files is not None:
            row = self.conn.execute(
                "SELECT digest FROM artifact_files WHERE evaluation = ? AND name = ?", (evaluation, name)
            ).fetchone()
            if row is not None:
                return self.files.get(row[0])
        if not self._has_artifacts:
            return None
        row = self.conn.execute(
            "SELECT data FROM artifacts WHERE evaluation = ? AND name = ?", (evaluation, name)
        ).fetchone()
        return None if row is None else _unpack_array(row[0])

    def artifact_digest(self, evaluation: str, name: str) -> str | None:
        """The name of the file an array is kept in beside the store (``None``: not kept as a
        file, or the file is gone) -- what a worker process reads it by, without the store."""
        if not self._has_files or self.files is None:
            return None
        row = self.conn.execute(
            "SELECT digest FROM artifact_files WHERE evaluation = ? AND name = ?", (evaluation, name)
        ).fetchone()
        return row[0] if row is not None and self.files.path(row[0]).is_file() else None

    def rows(self, *, dataset: str | None = None, kind: str | None = None,
             imported: bool = True) -> Iterator[ResultRow]:
        """Every row (this store's, then -- with ``imported`` -- those imported from other
        machines' bundles, :meth:`import_rows`), optionally of one dataset or kind."""
        yield from self._local_rows(dataset, kind)
        if imported and self._has_imported:
            for (text,) in self.conn.execute("SELECT row FROM imported ORDER BY machine, key"):
                row = row_from_dict(json.loads(text))
                if kind is not None and row.kind != kind:
                    continue
                if dataset is not None and not (row.dataset == dataset or row.dataset_id == dataset
                                                or row.dataset.startswith(dataset)):
                    continue
                yield row

    def _local_rows(self, dataset: str | None, kind: str | None) -> Iterator[ResultRow]:
        cols = [c if c in self._present else f"{_DEFAULTS[c]} AS {c}" for c in _COLUMNS]
        sql = f"SELECT {', '.join(cols)} FROM results"
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
            v = dict(zip(_COLUMNS, r, strict=True))
            extra = json.loads(v["extra"])
            yield ResultRow(
                kind=v["kind"],
                dataset=v["dataset"],
                dataset_id=v["dataset_id"],
                frame=v["frame"],
                codec=v["codec"],
                codec_version=v["codec_version"],
                params=json.loads(v["params"]),
                status=v["status"],
                metrics=metrics_from_json(json.loads(v["metrics"])),
                seed=v["seed"],
                error=v["error"],
                extra=extra,
                part=extra.get("part", ""),
                versions=json.loads(v["versions"]),
                lwbench_version=v["lwbench_version"],
                machine=v["machine"],
                created=v["created"],
                plugin_version=v["plugin_version"],
                scoring=json.loads(v["scoring"]),
                sensor_guessed=bool(v["sensor_guessed"]),
            )

    def count(self) -> int:
        return self.conn.execute("SELECT COUNT(*) FROM results").fetchone()[0]

    # -- what the rows were scored with (schema 5) --------------------------------------------
    def declare_metrics(self, declarations: Iterable[dict]) -> None:
        """Keep each scoring metric's declaration (``FrameMetric.describe()`` plus ``order``): its
        ids' units, directions, headline and guards. A board read from this store ranks and
        flags with these, not with whatever plugins the reading machine has installed."""
        if self.readonly:
            raise StoreError(f"{self.path} was opened read-only")
        with self.conn:
            self.conn.executemany(
                "INSERT OR REPLACE INTO metric_declarations VALUES (?, ?, ?)",
                [(d["name"], str(d["version"]), canonical_json(d)) for d in declarations],
            )

    def metric_declarations(self) -> list[dict]:
        """The declarations kept (:meth:`declare_metrics`), newest version of each metric last."""
        if not self._has_declarations:
            return []
        found = [json.loads(t) for (t,) in self.conn.execute(
            "SELECT declaration FROM metric_declarations ORDER BY name, version")]
        return found

    # -- other machines' rows (bundles: lwbench.results.bundle) --------------------------------
    def import_rows(self, rows: Iterable[ResultRow], bundle: str) -> int:
        """Keep rows another machine made (a bundle's), one per (machine, key): a configuration
        measured on two machines stays two rows -- same quality, each machine's runtimes.
        Imported rows are read by boards and reports, never taken as this machine's cache."""
        if self.readonly:
            raise StoreError(f"{self.path} was opened read-only")
        values = [(r.machine, r.key, canonical_json(row_to_dict(r)), bundle) for r in rows]
        with self.conn:
            self.conn.executemany("INSERT OR REPLACE INTO imported VALUES (?, ?, ?, ?)", values)
        return len(values)

    # -- suites (lwbench suite run) --------------------------------------------------------------
    def tag_suite(self, suite: str, keys: Iterable[str]) -> None:
        """Record that ``suite`` (``NAME@VERSION+HASH``) asked for the rows ``keys`` -- also rows
        an earlier run had stored (cache hits), so a suite's rows always say which suite made
        them."""
        if self.readonly:
            raise StoreError(f"{self.path} was opened read-only")
        with self.conn:
            self.conn.executemany("INSERT OR REPLACE INTO suite_rows VALUES (?, ?)", [(suite, k) for k in keys])

    def suites_of(self) -> dict[str, list[str]]:
        """Row key -> the suites that asked for it."""
        if not self._has_suites:
            return {}
        out: dict[str, list[str]] = {}
        for suite, key in self.conn.execute("SELECT suite, key FROM suite_rows ORDER BY suite"):
            out.setdefault(key, []).append(suite)
        return out


_DEFAULTS = {"plugin_version": "''", "scoring": "'[]'", "sensor_guessed": "0"}


def _unpack_array(blob: bytes) -> np.ndarray | None:
    """A blob in the store: :func:`lwbench.results.artifacts.pack_array` bytes (in-memory stores).
    Stores of schema 2 and before kept zstd ``.npy`` blobs here; 0.2 no longer reads them
    (issue 34: no 0.1 compatibility shims) -- such an array counts as not kept, which makes a
    run re-evaluate what needs it (the sequence stage re-decodes a frame whose payload is gone)
    and a report show no gallery cloud for it. Their rows are read as ever."""
    if blob[:4] == b"LWBC":
        return unpack_array(blob, "an array in the store")
    return None
