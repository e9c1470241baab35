"""The results store: read-only opening, recognition by schema, migration, refusal to write
into files that are not stores."""

from __future__ import annotations

import hashlib
import sqlite3

import pytest

from lwbench.errors import StoreError
from lwbench.results.store import SCHEMA_VERSION, ResultRow, ResultStore, is_results_store


def _row(frame: int = 0, **kw) -> ResultRow:
    return ResultRow("frame", "sim", "sim:abc", frame, "raw", "1", {}, "ok", {"bytes": 10.0 + frame}, 0, **kw)


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_store_round_trips_rows_with_their_scoring(tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        store.put(_row(plugin_version="lwbench==0.1.0", scoring=[["size", "1", {}, {}]]))
    with ResultStore(tmp_path / "r.sqlite", readonly=True) as store:
        (row,) = store.rows()
    assert row.plugin_version == "lwbench==0.1.0" and row.scoring == [["size", "1", {}, {}]]
    assert row.key == _row(plugin_version="lwbench==0.1.0", scoring=[["size", "1", {}, {}]]).key


def test_reading_a_store_writes_nothing(tmp_path):
    path = tmp_path / "r.sqlite"
    with ResultStore(path) as store:
        store.put(_row())
    before = _digest(path)
    with ResultStore(path, readonly=True) as store:
        assert len(list(store.rows())) == 1
        with pytest.raises(StoreError, match="read-only"):
            store.put(_row(1))
    assert _digest(path) == before


def test_another_sqlite_file_is_not_a_store_and_is_left_alone(tmp_path):
    # A ROS 2 bag is SQLite too (.db3): it must never be mistaken for a store or written into.
    bag = tmp_path / "rosbag.db3"
    conn = sqlite3.connect(bag)
    conn.execute("CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER, data BLOB)")
    conn.commit()
    conn.close()
    before = _digest(bag)
    assert not is_results_store(bag)
    for readonly in (True, False):
        with pytest.raises(StoreError, match="not an lwbench results store"):
            ResultStore(bag, readonly=readonly)
    assert _digest(bag) == before


def test_non_sqlite_files_and_folders_are_refused_clearly(tmp_path):
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(StoreError, match="not an lwbench results store"):
        ResultStore(tmp_path / "notes.txt")
    with pytest.raises(StoreError, match="directory"):
        ResultStore(tmp_path)
    with pytest.raises(StoreError, match="no results store"):
        ResultStore(tmp_path / "missing.sqlite", readonly=True)


def test_a_schema_1_store_is_read_and_migrated(tmp_path):
    path = tmp_path / "old.sqlite"
    conn = sqlite3.connect(path)
    conn.executescript(
        """
        CREATE TABLE results (key TEXT PRIMARY KEY, kind TEXT, dataset TEXT, dataset_id TEXT, frame INTEGER,
            codec TEXT, codec_version TEXT, params TEXT, status TEXT, error TEXT, metrics TEXT, extra TEXT,
            seed INTEGER, lwbench_version TEXT, versions TEXT, machine TEXT, created TEXT);
        CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
        INSERT INTO meta VALUES ('schema_version', '1');
        INSERT INTO results VALUES ('k1', 'frame', 'sim', 'sim:abc', 0, 'raw', '1', '{}', 'ok', NULL,
            '{"bytes": 5.0}', '{}', 0, '0.1.0', '{}', 'host', '2026-11-01T00:00:00+00:00');
        """
    )
    conn.commit()
    conn.close()
    with ResultStore(path, readonly=True) as store:
        (row,) = store.rows()
        assert row.metrics == {"bytes": 5.0} and row.plugin_version == "" and row.scoring == []
    with ResultStore(path) as store:  # opening for writing migrates in place
        store.put(_row(3))
        assert store.count() == 2
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0] == str(SCHEMA_VERSION)
    conn.close()


def test_a_store_from_a_newer_lwbench_is_refused(tmp_path):
    path = tmp_path / "new.sqlite"
    with ResultStore(path) as store:
        store.put(_row())
    conn = sqlite3.connect(path)
    conn.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    conn.commit()
    conn.close()
    with pytest.raises(StoreError, match="newer"):
        ResultStore(path, readonly=True)


def test_decoded_clouds_are_files_beside_the_store_content_addressed_and_compressed(tmp_path):
    import numpy as np

    from lwbench.results.artifacts import CloudFiles, pack_array, unpack_array

    rng = np.random.default_rng(0)
    cloud = (rng.normal(0, 10, (5000, 3))).astype(np.float32)
    path = tmp_path / "r.sqlite"
    with ResultStore(tmp_path / "empty.sqlite"):
        pass
    empty = (tmp_path / "empty.sqlite").stat().st_size  # the tables and their indexes, no row
    with ResultStore(path) as store:
        store.put(_row(0), {"decoded": cloud})
        store.put(_row(1), {"decoded": cloud})  # the same cloud: one file
        store.put_artifact("original:sim:abc:0", "points", cloud[:10])
    files = sorted((tmp_path / "r.clouds").rglob("*.lwbc"))
    # The store keeps names, not clouds: it grows by far less than one 60 kB cloud.
    assert len(files) == 2 and path.stat().st_size - empty < cloud.nbytes / 4
    assert sum(f.stat().st_size for f in files) < cloud.nbytes  # shuffled + zstd
    with ResultStore(path, readonly=True) as store:
        (a, b) = (store.artifact(r.evaluation, "decoded") for r in store.rows())
        assert np.array_equal(a, cloud) and np.array_equal(b, cloud) and a.dtype == np.float32
        assert np.array_equal(store.artifact("original:sim:abc:0", "points"), cloud[:10])
        assert store.artifact("nothing", "decoded") is None
    assert np.array_equal(unpack_array(pack_array(np.zeros((0, 3), np.float32))), np.zeros((0, 3), np.float32))
    # A damaged or edited file is an error, never a silently different cloud.
    files[0].write_bytes(files[0].read_bytes()[:-3])
    with pytest.raises(StoreError, match="damaged|does not hold"):
        CloudFiles.beside(path).get(files[0].stem)


def test_an_older_stores_rows_stay_readable_its_zstd_clouds_count_as_not_kept(tmp_path):
    """A schema-2 store kept decoded clouds as zstd .npy blobs in the artifacts table. The 0.1
    shim that read them is gone (issue 34): such a cloud is not kept (``None``: what needs it is
    evaluated again), its rows read as ever, and a run into it migrates it and writes its new
    clouds as files."""
    import io

    import numpy as np
    import zstandard

    path = tmp_path / "old.sqlite"
    cloud = np.arange(30, dtype=np.float32).reshape(10, 3)
    with ResultStore(path) as store:
        store.put(_row(0))
    buf = io.BytesIO()
    np.save(buf, cloud, allow_pickle=False)
    conn = sqlite3.connect(path)
    with conn:
        conn.execute("DROP TABLE artifact_files")
        conn.execute("UPDATE meta SET value = '2' WHERE key = 'schema_version'")
        conn.execute("INSERT INTO artifacts VALUES (?, 'decoded', ?)",
                     (_row(0).evaluation, zstandard.ZstdCompressor().compress(buf.getvalue())))
    conn.close()
    with ResultStore(path, readonly=True) as store:
        assert store.artifact(_row(0).evaluation, "decoded") is None
        assert store.status(_row(0).key) == "ok"
    with ResultStore(path) as store:
        store.put(_row(1), {"decoded": cloud * 2})
        assert store.artifact(_row(0).evaluation, "decoded") is None
        assert np.array_equal(store.artifact(_row(1).evaluation, "decoded"), cloud * 2)
    assert len(list((tmp_path / "old.clouds").rglob("*.lwbc"))) == 1
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0] == str(SCHEMA_VERSION)


def _open_and_close(path: str, start, results) -> None:
    start.wait()
    try:
        ResultStore(path).close()
        results.put("ok")
    except StoreError as exc:
        results.put(str(exc))


@pytest.mark.heavy
@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork to start the racers together")
def test_runs_that_open_a_new_store_at_the_same_moment_all_get_it(tmp_path):
    """Switching a new file to WAL takes an exclusive lock and SQLite does not wait for it: three
    processes opening one new store at the same moment failed in 31 of 150 races ("database is
    locked") before the switch was retried."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    failures = []
    for i in range(30):
        start, results = ctx.Barrier(3), ctx.Queue()
        procs = [ctx.Process(target=_open_and_close, args=(str(tmp_path / f"{i}.sqlite"), start, results))
                 for _ in range(3)]
        for p in procs:
            p.start()
        for p in procs:
            p.join(60)
        failures += [r for r in (results.get(timeout=10) for _ in procs) if r != "ok"]
    assert failures == []
