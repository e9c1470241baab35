"""Issue 25, on the board: rows scored on a guessed sensor model say so (``sensor guessed``) in
every format -- terminal table, md, csv, json, the HTML report -- stored with each row (a
store of an older lwbench reads as not guessed); a caveat about the data moves no row, while
quality flags still rank last."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from _scans import shuffled, street_scan, voxel_downsampled, write_bin
from lwbench_plugins.files import KittiDataset
from typer.testing import CliRunner

from lwbench import DataWarning, get_sensor
from lwbench.cli import app
from lwbench.io import read_kitti_bin
from lwbench.registry import get_registry
from lwbench.results.leaderboard import CAVEATS, build_leaderboard
from lwbench.results.rd import curves_from_entries
from lwbench.results.store import SCHEMA_VERSION, ResultRow, ResultStore
from lwbench.sensors.derive import METHOD_PRESET

runner = CliRunner()
INFO = get_registry().metric_info()


def _keyframe_folder(root: Path, scans: list[np.ndarray]) -> Path:
    """Scans as public keyframe sets hold them: voxel-downsampled (0.2 m), shuffled, no ring
    field, no sensor file, KITTI ``.bin`` with a non-zero intensity column."""
    folder = root / "velodyne"
    folder.mkdir(parents=True)
    for i, pts in enumerate(scans):
        kept = shuffled(voxel_downsampled(pts, 0.2), seed=i)
        write_bin(folder / f"{i:06d}.bin", kept, np.full(len(kept), 0.5, np.float32))
    return root


def _run_and_boards(dataset: Path, store: Path) -> dict[str, str]:
    with pytest.warns(DataWarning, match="guessed"):
        res = runner.invoke(
            app,
            [
                "run",
                "--dataset",
                str(dataset),
                "--codec",
                "raw",
                "--codec",
                "random",
                "--codec",
                "rangeimage",
                "--store",
                str(store),
            ],
            catch_exceptions=False,
        )
    assert res.exit_code == 0, res.output
    out = {"run": res.stdout}
    for fmt in ("json", "md", "csv", "table"):
        res = runner.invoke(app, ["leaderboard", "--store", str(store), "--format", fmt], catch_exceptions=False)
        assert res.exit_code == 0, res.output
        out[fmt] = res.stdout
    return out


@pytest.mark.heavy
def test_a_voxel_downsampled_shuffled_hdl64e_folder_is_flagged_sensor_guessed_on_every_board(tmp_path):
    root = _keyframe_folder(tmp_path / "keyframes", [street_scan(get_sensor("hdl64e"), seed=0, laser_height_m=0.2)])
    with pytest.warns(DataWarning, match="guessed"):
        choice = KittiDataset(path=str(root)).sensor_choice
    assert choice.guessed  # snapped to a preset or not, a guess is a guess
    boards = _run_and_boards(root, tmp_path / "r.sqlite")
    rows = json.loads(boards["json"])
    assert {r["codec"] for r in rows} == {"raw", "random", "rangeimage"}
    assert all("sensor_guessed" in r["flags"] for r in rows), rows
    # Every other format says it too: the text on each row of the tables, the id in the csv.
    md_rows = [line for line in boards["md"].splitlines()[2:] if line.startswith("|")]
    assert len(md_rows) == 3 and all("sensor guessed" in line for line in md_rows)
    assert boards["csv"].count("sensor_guessed") == 3
    for text in (boards["table"], boards["run"]):
        table_rows = [line for line in text.splitlines() if line.split()[:1] in (["raw"], ["random"], ["rangeimage"])]
        assert len(table_rows) == 3 and all("sensor guessed" in line for line in table_rows)
        assert "the dataset's beam table was guessed from the data" in text  # said once, under the table
    # A caveat about the data moves no row: raw (exact) is first, random (low coverage) last.
    assert [r["codec"] for r in rows] == ["rangeimage", "raw", "random"]
    assert rows[-1]["flags"] == ["low_coverage", "sensor_guessed"]


@pytest.mark.heavy
def test_the_same_folder_with_its_sensor_named_carries_no_flag(tmp_path):
    root = _keyframe_folder(tmp_path / "keyframes", [street_scan(get_sensor("hdl64e"), seed=0)])
    store = tmp_path / "named.sqlite"
    res = runner.invoke(
        app,
        ["run", "--dataset", str(root), "--dataset-param", "sensor=hdl64e", "--codec", "raw", "--store", str(store)],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    rows = json.loads(runner.invoke(app, ["leaderboard", "--store", str(store), "--format", "json"]).stdout)
    assert rows[0]["flags"] == [] and "sensor guessed" not in res.stdout


@pytest.mark.heavy
def test_a_real_voxel_downsampled_hdl64e_keyframe_carries_sensor_guessed_in_the_json_board(real_data, tmp_path):
    """The issue's done-when on the real KITTI frame 0: voxel-downsampled, shuffled, no ring."""
    pts = read_kitti_bin(real_data / "kitti00_frames0-1" / "000000.bin").points
    root = _keyframe_folder(tmp_path / "keyframes", [pts])
    with pytest.warns(DataWarning, match="guessed"):
        choice = KittiDataset(path=str(root)).sensor_choice
    # Snapped to the 64-beam preset, or a guess that is not a preset: flagged either way.
    assert choice.guessed and (choice.sensor.n_beams == 64 or choice.derivation.method != METHOD_PRESET)
    rows = json.loads(_run_and_boards(root, tmp_path / "r.sqlite")["json"])
    assert rows and all("sensor_guessed" in r["flags"] for r in rows)


# ----------------------------------------------------------------------------- the board's rules
def _row(codec: str, frame: int, metrics: dict, *, guessed: bool = False, dataset: str = "d") -> ResultRow:
    return ResultRow(
        "frame",
        dataset,
        f"{dataset}:1",
        frame,
        codec,
        "1",
        {},
        "ok",
        metrics,
        0,
        sensor_guessed=guessed,
        created="2026-12-01T00:00:00+00:00",
    )


def test_sensor_guessed_is_a_caveat_not_a_quality_flag(tmp_path):
    assert "sensor_guessed" in CAVEATS
    with ResultStore(tmp_path / "r.sqlite") as store:
        for f in range(2):
            store.put(
                _row("good", f, {"bytes": 100.0, "ratio": 10.0, "coverage": 1.0, "range_rmsd": 0.01}, guessed=True)
            )
            store.put(
                _row("small", f, {"bytes": 50.0, "ratio": 20.0, "coverage": 0.5, "range_rmsd": 0.001}, guessed=True)
            )
            store.put(_row("exact", f, {"bytes": 80.0, "ratio": 12.5, "coverage": 1.0, "range_rmsd": 0.02}))
        entries = build_leaderboard(store, info=INFO, sort="ratio")
    by = {e.codec: e for e in entries}
    assert by["good"].flags == ["sensor_guessed"] and not by["good"].ranked_last
    assert by["small"].flags == ["low_coverage", "sensor_guessed"] and by["small"].ranked_last
    assert by["exact"].flags == []
    # By ratio, best first; the guessed row is not moved after the exact one, the low-coverage one is.
    assert [e.codec for e in entries] == ["exact", "good", "small"]
    # The caveat keeps nothing off the rate-distortion curves (low coverage keeps small off range_rmsd).
    left_out: list = []
    curves = curves_from_entries(entries, "range_rmsd", rate="bytes", info=INFO, left_out=left_out)
    assert {k[1] for k in curves} == {"good", "exact"}
    assert [(e.codec, why.split(":")[0]) for e, why in left_out] == [("small", "low_coverage")]


def test_a_store_of_an_older_lwbench_reads_as_not_guessed_and_is_migrated(tmp_path):
    path = tmp_path / "old.sqlite"
    with ResultStore(path) as store:
        store.put(_row("raw", 0, {"bytes": 5.0}))
    conn = sqlite3.connect(path)  # what a schema-3 store is: the same table without the column
    conn.execute("ALTER TABLE results DROP COLUMN sensor_guessed")
    conn.execute("UPDATE meta SET value = '3' WHERE key = 'schema_version'")
    conn.commit()
    conn.close()
    with ResultStore(path, readonly=True) as store:
        (row,) = store.rows()
        assert row.sensor_guessed is False
        assert build_leaderboard(store, info=INFO)[0].flags == []
    with ResultStore(path) as store:  # written into: migrated in place, the old row kept
        store.put(_row("raw", 1, {"bytes": 6.0}, guessed=True))
        assert sorted(r.sensor_guessed for r in store.rows()) == [False, True]
    conn = sqlite3.connect(path)
    assert conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0] == str(SCHEMA_VERSION)
    conn.close()


def test_the_bag_reader_says_when_it_guessed(tmp_path):
    from lwbench import Frame
    from lwbench.bags import BagDataset, frames_to_clouds, write_bag

    hdl = get_sensor("hdl64e")
    pts = shuffled(voxel_downsampled(street_scan(hdl, seed=0), 0.2))
    write_bag(tmp_path / "bag", frames_to_clouds([Frame(pts, hdl, index=0)]), sensor=None, storage="mcap")
    with pytest.warns(DataWarning, match="guessed"):
        ds = BagDataset(path=str(tmp_path / "bag"))
        assert ds.sensor_guessed and ds.source_info()["sensor guessed"] is True
    named = BagDataset(path=str(tmp_path / "bag"), sensor="hdl64e")
    assert not named.sensor_guessed
