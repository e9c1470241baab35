"""The SQLite side of the store: how a store is opened (WAL, read-only, busy waits) and how a
file is recognised as one -- by its tables, not by being SQLite."""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable, Iterable
from pathlib import Path

__all__ = ["BUSY_TIMEOUT_S", "connect_readonly", "connect_writable", "empty_sqlite", "schema_version",
           "table_columns"]


def table_columns(conn: sqlite3.Connection, table: str) -> set[str]:
    return {r[1] for r in conn.execute(f"PRAGMA table_info({table})")}


def schema_version(conn: sqlite3.Connection, columns: Iterable[str]) -> int | None:
    """The store schema of an open SQLite database, or ``None`` if it is not a results store.

    Recognised by its tables, not by being SQLite: a ROS 2 bag (``.db3``) or any other
    application's database is SQLite too."""
    try:
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    except sqlite3.DatabaseError:
        return None
    if not {"results", "meta"} <= tables or not set(columns) <= table_columns(conn, "results"):
        return None
    row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
    try:
        return int(row[0]) if row else None
    except ValueError:
        return None


#: How long opening a store waits for another process that holds it (SQLite's busy timeout).
BUSY_TIMEOUT_S = 30.0


def connect_writable(path: Path) -> sqlite3.Connection:
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


def connect_readonly(path: Path) -> sqlite3.Connection:
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


def ask_sqlite(path: Path, question: Callable[[sqlite3.Connection], bool]) -> bool:
    """``question`` about the SQLite file at ``path``, asked read-only; False for anything that
    is not a readable SQLite database (checked by its magic bytes before SQLite opens it)."""
    with open(path, "rb") as fh:
        if fh.read(16) != b"SQLite format 3\x00":
            return False
    try:
        conn = connect_readonly(path)
    except sqlite3.Error:
        return False
    try:
        return question(conn)
    except sqlite3.DatabaseError:
        return False
    finally:
        conn.close()


def empty_sqlite(path: Path) -> bool:
    """An SQLite database with no table at all (a store being created by another process)."""
    return ask_sqlite(path, lambda conn: conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0] == 0)
