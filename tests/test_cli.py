"""The CLI contract of DESIGN.md: forms, JSON shapes, clear errors instead of tracebacks."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from lwbench.cli import app

runner = CliRunner()


def invoke(*args: str):
    return runner.invoke(app, list(args), catch_exceptions=False)


def test_list_json_has_codecs_datasets_metrics_and_providers():
    res = invoke("list", "--json")
    assert res.exit_code == 0
    data = json.loads(res.stdout)
    codecs = {c["name"]: c for c in data["codecs"]}
    assert codecs["random"]["kind"] == "selection"
    assert {p["name"] for p in codecs["random"]["params"]} >= {"ratio", "points", "seed", "encoding"}
    assert codecs["raw"]["provider"].startswith("lwbench")
    assert {"kitti", "files"} <= {d["name"] for d in data["datasets"]}
    assert any("range_rmsd" in m["ids"] for m in data["metrics"])


@pytest.fixture(scope="module")
def store(tmp_path_factory, real_data):
    path = tmp_path_factory.mktemp("cli") / "r.sqlite"
    res = invoke("run", "--dataset", str(real_data / "kitti_object_000008"), "--codec", "raw",
                 "--codec", "random", "--param", "random.ratio=0.1,0.3", "--store", str(path))
    assert res.exit_code == 0, res.output
    assert "Leaderboard" in res.stdout and "random(ratio=0.3)" in res.stdout
    return path


def test_run_on_a_real_sample_prints_every_core_metric_column(store):
    res = invoke("leaderboard", "--store", str(store), "--format", "md")
    assert res.exit_code == 0
    header = res.stdout.splitlines()[0]
    for col in ("bytes", "ratio", "range_rmsd", "coverage", "chamfer", "d1_psnr", "encode_ms", "decode_ms"):
        assert col in header


def test_leaderboard_json_contract(store):
    data = json.loads(invoke("leaderboard", "--store", str(store), "--format", "json", "--sort", "ratio").stdout)
    # Both random configurations keep < 90 % of the returns: flagged, so they rank after raw.
    assert [d["codec"] for d in data] == ["raw", "random", "random"]
    assert data[0]["flags"] == [] and data[1]["flags"] == data[2]["flags"] == ["low_coverage"]
    for d in data:
        for key in ("dataset", "codec", "params", "frames", "failures", "flags", "bytes", "bytes_median",
                    "bytes_p95", "range_rmsd", "coverage", "chamfer_p95"):
            assert key in d
    assert data[1]["params"]["ratio"] == 0.1 and data[1]["ratio"] > data[2]["ratio"]
    assert data[0]["d1_psnr"] is None  # +inf for lossless is not valid JSON


def test_leaderboard_csv(store):
    lines = invoke("leaderboard", "--store", str(store), "--format", "csv").stdout.splitlines()
    assert lines[0].startswith("dataset,dataset_id,codec,params,frames,failures") and len(lines) == 4


def test_rerun_is_a_cache_hit(store, real_data):
    res = invoke("run", "--dataset", str(real_data / "kitti_object_000008"), "--codec", "raw",
                 "--store", str(store))
    assert "evaluated 0, cached 1 of 1" in res.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (("run", "--codec", "nope", "--dataset", "kitti"), "unknown codec 'nope'"),
        (("run", "--codec", "random", "--param", "random.ratio=2", "--dataset", "/nonexistent/x"), "does not exist"),
        (("run", "--codec", "raw", "--param", "random.ratio=0.1"), "not in this run's --codec list"),
        (("run", "--codec", "raw", "--param", "ratio=0.1"), "CODEC.KEY=VALUE"),
        (("leaderboard", "--store", "/nonexistent/r.sqlite"), "no results store"),
    ],
)
def test_user_errors_are_one_clear_line_and_exit_2(args, message):
    res = invoke(*args)
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output


def test_bad_parameter_value_is_a_clear_error(real_data, tmp_path):
    res = invoke("run", "--dataset", str(real_data / "kitti_object_000008"), "--codec", "random",
                 "--param", "random.ratio=1.5", "--store", str(tmp_path / "x.sqlite"))
    assert res.exit_code == 2 and "above the maximum" in res.output


def test_inspect_payload_scan_and_store(tmp_path, store, real_data, vlp16_frame):
    from lwbench.registry import get_registry

    payload = get_registry().codec("raw")().encode(vlp16_frame)
    (tmp_path / "p.lwb").write_bytes(payload)
    out = invoke("inspect", str(tmp_path / "p.lwb")).stdout
    assert "lwbench payload" in out and "57600" in out.replace(",", "")
    (tmp_path / "bad.lwb").write_bytes(payload[:-3])
    res = invoke("inspect", str(tmp_path / "bad.lwb"))
    assert res.exit_code == 2 and "checksum" in res.output
    assert "KITTI" in invoke("inspect", str(real_data / "kitti00_frames0-1")).stdout.upper()
    assert "results store" in invoke("inspect", str(store)).stdout


def test_changed_data_under_the_same_label_is_not_averaged_in(tmp_path):
    import numpy as np

    from lwbench.leaderboard import build_leaderboard
    from lwbench.store import ResultRow, ResultStore

    with ResultStore(tmp_path / "r.sqlite") as store:
        for ds_id, value in (("sim:v1", 1.0), ("sim:v2", 3.0)):
            store.put(ResultRow("frame", "sim", ds_id, 0, "raw", "1", {}, "ok", {"bytes": value}, 0))
        entries = build_leaderboard(store)
    assert sorted(e.value("bytes") for e in entries) == [1.0, 3.0]
    assert len({e.dataset for e in entries}) == 2 and not np.isnan(entries[0].value("bytes"))
