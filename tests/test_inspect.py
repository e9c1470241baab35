"""``lwbench inspect``: reading never writes, and what a loader derived or skipped is shown."""

from __future__ import annotations

import hashlib
import sqlite3

import numpy as np
import pytest
from _scans import spinning_scan, write_bin
from typer.testing import CliRunner

from lwbench.cli import app
from lwbench.errors import DataFormatError
from lwbench.inspection import describe, is_results_store
from lwbench.registry import get_registry
from lwbench.results.store import SCHEMA_VERSION, ResultRow, ResultStore


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _ros2_bag_like(path) -> None:
    """An SQLite file with tables of its own, as a ROS 2 ``.db3`` bag has (and even a table
    named ``results``, with other columns)."""
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE topics (id INTEGER PRIMARY KEY, name TEXT, type TEXT)")
        conn.execute("CREATE TABLE messages (id INTEGER PRIMARY KEY, topic_id INTEGER, timestamp INTEGER, data BLOB)")
        conn.execute("CREATE TABLE results (id INTEGER, value REAL)")
        conn.execute("INSERT INTO topics VALUES (1, '/velodyne_points', 'sensor_msgs/msg/PointCloud2')")
        conn.execute("INSERT INTO messages VALUES (1, 1, 0, x'00ff')")
    conn.close()


def test_inspecting_another_sqlite_file_leaves_its_bytes_and_folder_unchanged(tmp_path):
    bag = tmp_path / "bag" / "rosbag2_0.db3"
    bag.parent.mkdir()
    _ros2_bag_like(bag)
    before, files = _digest(bag), sorted(p.name for p in bag.parent.iterdir())
    assert not is_results_store(bag)
    with pytest.raises(DataFormatError, match="not an lwbench results store.*inspect reads"):
        describe(bag, get_registry())
    res = CliRunner().invoke(app, ["inspect", str(bag)])
    assert res.exit_code == 2 and "not an lwbench results store" in res.output
    assert _digest(bag) == before
    assert sorted(p.name for p in bag.parent.iterdir()) == files  # no -journal, -wal, -shm


def test_a_results_store_is_recognised_by_its_schema_and_read_without_writing(tmp_path):
    path = tmp_path / "r.sqlite"
    with ResultStore(path) as store:
        for frame, status in ((0, "ok"), (1, "failed")):
            store.put(ResultRow("frame", "sim", "sim:1", frame, "raw", "1", {}, status, {"bytes": 1.0}, 0))
    before = _digest(path)
    assert is_results_store(path)
    info = describe(path, get_registry())
    got = (info["rows"], info["failed rows"], info["codecs"], info["schema version"])
    assert got == (2, 1, ["raw"], str(SCHEMA_VERSION))
    assert _digest(path) == before


def test_a_sqlite_file_with_lwbench_tables_but_no_schema_version_is_not_a_store(tmp_path):
    path = tmp_path / "r.sqlite"
    with ResultStore(path):
        pass
    with sqlite3.connect(path) as conn:
        conn.execute("DELETE FROM meta")
    conn.close()
    assert not is_results_store(path)


def test_inspect_shows_how_the_sensor_was_derived_and_what_was_skipped(tmp_path):
    for i in range(2):
        write_bin(tmp_path / f"{i:06d}.bin", spinning_scan("hdl64e", order="ring", elevation_noise_deg=0.2, seed=i))
    np.zeros(100, "<f4").tofile(tmp_path / "notes.bin")  # (a times_000000.bin would be read as 000000's times)
    info = describe(tmp_path, get_registry())
    assert info["kind"] == "scan data (kitti loader)" and info["frames"] == 2
    assert info["skipped files"] == ["notes.bin"]
    assert any("notes.bin" in w for w in info["warnings"])
    derived = info["derived sensor"]
    assert derived["method"] == "ring-major order" and derived["beams"] == 64 and derived["columns"] == 2048
    assert info["sensor source"] == "derived from 000000.bin (ring-major order)"


def test_inspect_shows_a_guessed_table_with_its_warning(tmp_path):
    pts = spinning_scan("vlp16", order="ring")
    write_bin(tmp_path / "000000.bin", pts[np.random.default_rng(0).permutation(len(pts))])
    info = describe(tmp_path, get_registry())
    # No order left: the VLP-16's table is the preset that fits -- a guess, and shown as one.
    assert info["derived sensor"]["method"] == "preset table fitted to the elevations"
    assert info["derived sensor"]["guessed"] and "snapped to preset vlp16" in info["derived sensor"]["rule"]
    assert info["sensor guessed"] is True
    assert "sensor=" in info["derived sensor"]["warnings"][0]
    assert len(info["derived sensor"]["order readings rejected"]) == 2


def test_inspect_on_the_real_kitti_folder_shows_64_beams(real_data):
    info = describe(real_data / "kitti00_frames0-1", get_registry())
    assert info["derived sensor"]["beams"] == 64 and info["derived sensor"]["method"] == "ring-major order"
    assert 2000 <= info["derived sensor"]["columns"] <= 2100
    assert "calib.txt" in info["poses from"]
