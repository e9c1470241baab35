"""The results store: one SQLite row per (dataset, frame, codec, parameters) evaluation.

SQLite in WAL mode with one transaction per row, so a killed run loses at most the row being
computed, readers (``lwbench leaderboard``) never block the writer, and a re-run skips every
key already stored. Each row carries its provenance -- lwbench, plugin and library versions,
machine, seed -- because a number nobody can reproduce is worth little. The arrays a row keeps
(decoded clouds, the originals a report shows) are files beside the store, content-addressed
and compressed (:mod:`lwbench.results.artifacts`); the store holds their names.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from lwbench.errors import StoreError
from lwbench.results.artifacts import CloudFiles, pack_array, unpack_array

__all__ = ["ResultStore", "ResultRow", "evaluation_key", "result_key", "environment_versions", "is_results_store"]

# 2: rows carry the codec plugin's package version and the scoring signature (metric names,
#    versions, parameters and settings), both part of the key.
# 3: arrays are files beside the store (table artifact_files: their names); older stores' arrays
#    stay readable in the artifacts table.
# 4: rows say whether the dataset's sensor model was guessed (column sensor_guessed; rows of older
#    stores read as not guessed -- nobody recorded it then). An older lwbench refuses a schema-4
#    store rather than show its guessed rows without their flag.
SCHEMA_VERSION = 4
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
"""
# Columns added after schema 1, with the values old rows get.
_ADDED = {
    "plugin_version": "TEXT NOT NULL DEFAULT ''",
    "scoring": "TEXT NOT NULL DEFAULT '[]'",
    "sensor_guessed": "INTEGER NOT NULL DEFAULT 0",
}


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def evaluation_key(
    dataset_id: str, frame: int, codec: str, codec_version: str, plugin_version: str, params: dict, seed: int
) -> str:
    """What was *encoded*: the same data through the same code and parameters gives the same
    decoded cloud, whatever it is scored with (artifacts such as decoded clouds use this)."""
    blob = canonical_json([dataset_id, frame, codec, codec_version, plugin_version, params, seed])
    return hashlib.sha256(blob.encode()).hexdigest()


def result_key(evaluation: str, kind: str, part: str, scoring: list) -> str:
    """The identity of one row: an evaluation scored by a given set of metric versions and
    parameters. Same inputs, same key, so a re-run is a cache hit; a fixed metric, a changed
    metric parameter or a new plugin release is a different key and recomputes."""
    blob = canonical_json([evaluation, kind, part, scoring])
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
    plugin_version: str = ""
    scoring: list = field(default_factory=list)
    # Whether the dataset's sensor model was a guess (derived without ring labels) when this row
    # was scored: its range metrics stand on that guessed beam table. Not part of the key (the
    # same data and code give the same guess).
    sensor_guessed: bool = False

    @property
    def evaluation(self) -> str:
        return evaluation_key(
            self.dataset_id, self.frame, self.codec, self.codec_version, self.plugin_version, self.params, self.seed
        )

    @property
    def key(self) -> str:
        return result_key(self.evaluation, self.kind, self.part, self.scoring)


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


def _columns(conn: sqlite3.Connection, table: str) -> set[str]:
    return {r[1] for r in conn.execute(f"PRAGMA table_info({table})")}


def _schema_version(conn: sqlite3.Connection) -> int | None:
    """The store schema of an open SQLite database, or ``None`` if it is not a results store.

    Recognised by its tables, not by being SQLite: a ROS 2 bag (``.db3``) or any other
    application's database is SQLite too."""
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError:
        return None
    if not {"results", "meta"} <= tables or not set(_COLUMNS) - set(_ADDED) <= _columns(conn, "results"):
        return None
    row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    try:
        return int(row[0]) if row else None
    except ValueError:
        return None


#: How long opening a store waits for another process that holds it (SQLite's busy timeout).
BUSY_TIMEOUT_S = 30.0


def _connect_writable(path: Path) -> sqlite3.Connection:
    """A connection in WAL mode. Switching a database to WAL takes an exclusive lock, and SQLite
    answers "database is locked" at once -- without waiting the busy timeout -- when another
    connection holds the file at that moment: two runs started together on a new store hit it
    (31 of 150 three-process races here). So the switch is retried until the busy timeout, and
    skipped when the file is already in WAL mode (reading the mode takes no lock)."""
    conn = sqlite3.connect(str(path), timeout=BUSY_TIMEOUT_S)
    deadline = time.monotonic() + BUSY_TIMEOUT_S
    while True:
        try:
            if conn.execute("PRAGMA journal_mode").fetchone()[0].lower() != "wal":
                conn.execute("PRAGMA journal_mode=WAL")
            conn.execute("PRAGMA synchronous=NORMAL")
            return conn
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc) and "busy" not in str(exc) or time.monotonic() > deadline:
                conn.close()
                raise
            time.sleep(0.02)


def _connect_readonly(path: Path) -> sqlite3.Connection:
    """A connection that cannot write (``mode=ro``). A WAL database in a folder we may not write
    to cannot be opened so (SQLite needs its ``-shm`` file); it is then read as ``immutable``,
    which is right for a store no run is writing to."""
    uri = path.resolve().as_uri()
    conn = sqlite3.connect(f"{uri}?mode=ro", uri=True, timeout=30.0)
    try:
        conn.execute("SELECT 1 FROM sqlite_master LIMIT 1").fetchall()
    except sqlite3.OperationalError:
        conn.close()
        conn = sqlite3.connect(f"{uri}?mode=ro&immutable=1", uri=True, timeout=30.0)
    return conn


def _ask_sqlite(path: Path, question: Callable[[sqlite3.Connection], bool]) -> bool:
    """``question`` about the SQLite file at ``path``, asked read-only; False for anything that
    is not a readable SQLite database (checked by its magic bytes before SQLite opens it)."""
    with open(path, "rb") as fh:
        if fh.read(16) != b"SQLite format 3\x00":
            return False
    try:
        conn = _connect_readonly(path)
    except sqlite3.Error:
        return False
    try:
        return question(conn)
    except sqlite3.DatabaseError:
        return False
    finally:
        conn.close()


def is_results_store(path: str | Path) -> bool:
    """Whether ``path`` is an lwbench results store (checked read-only: nothing is written)."""
    path = Path(path)
    return path.is_file() and _ask_sqlite(path, lambda conn: _schema_version(conn) is not None)


def _empty_sqlite(path: Path) -> bool:
    """An SQLite database with no table at all (a store being created by another process)."""
    return _ask_sqlite(path, lambda conn: conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0] == 0)


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
        if exists and not readonly and _empty_sqlite(self.path):
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
                self.conn = _connect_readonly(self.path)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.conn = _connect_writable(self.path)
        except (sqlite3.Error, OSError) as exc:
            raise StoreError(f"cannot open results store {self.path}: {exc}") from None
        version = _schema_version(self.conn) if exists else SCHEMA_VERSION
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
                    missing = {c: t for c, t in _ADDED.items() if c not in _columns(self.conn, "results")}
                    for column, decl in missing.items():
                        self.conn.execute(f"ALTER TABLE results ADD COLUMN {column} {decl}")
                    self.conn.execute(
                        "INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
                    )
            except sqlite3.Error as exc:
                self.conn.close()
                raise StoreError(f"cannot write results store {self.path}: {exc}") from None
        self._present = _columns(self.conn, "results")
        self._has_artifacts = bool(_columns(self.conn, "artifacts"))
        self._has_files = bool(_columns(self.conn, "artifact_files"))
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
            "metrics": json.dumps(_json_safe(row.metrics), sort_keys=True),
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

    def rows(self, *, dataset: str | None = None, kind: str | None = None) -> Iterator[ResultRow]:
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
                metrics=_from_json(json.loads(v["metrics"])),
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
