"""The CLI contract of docs/design.md: forms, JSON shapes, clear errors instead of tracebacks."""

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
def store(tmp_path_factory, kitti_folder):
    path = tmp_path_factory.mktemp("cli") / "r.sqlite"
    res = invoke("run", "--dataset", str(kitti_folder), "--codec", "raw",
                 "--codec", "random", "--param", "random.ratio=0.1,0.3", "--store", str(path))
    assert res.exit_code == 0, res.output
    assert "Leaderboard" in res.stdout and "random(ratio=0.3)" in res.stdout
    return path


@pytest.mark.heavy
def test_run_prints_every_core_metric_column(store):
    res = invoke("leaderboard", "--store", str(store), "--format", "md")
    assert res.exit_code == 0
    header = res.stdout.splitlines()[0]
    for col in ("bytes", "ratio", "range_rmsd", "coverage", "chamfer", "encode_ms", "decode_ms"):
        assert col in header
    # Behind --columns (the default board fits 120 columns): select_ms is part of encode_ms.
    assert not {"d1_psnr", "false_returns", "select_ms"} & set(header.replace("|", " ").split())


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


def test_rerun_is_a_cache_hit(store, kitti_folder):
    res = invoke("run", "--dataset", str(kitti_folder), "--codec", "raw",
                 "--store", str(store))
    assert "evaluated 0, cached 3 of 3" in res.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (("run", "--codec", "nope", "--dataset", "kitti"), "unknown codec 'nope'"),
        (("run", "--codec", "random", "--param", "random.ratio=2", "--dataset", "/nonexistent/x"), "does not exist"),
        (("run", "--codec", "raw", "--param", "random.ratio=0.1"), "not in this run's --codec list"),
        (("run", "--codec", "raw", "--param", "ratio=0.1"), "CODEC.KEY=VALUE"),
        (("leaderboard", "--store", "/nonexistent/r.sqlite"), "no results store"),
        # A curve needs a sweep: the hint names the run file, not a plain `lwbench run` (issue 33).
        (("rd", "--store", "/nonexistent/r.sqlite"), "lwbench run --config examples/runs/rd_tunnel.toml"),
    ],
)
def test_user_errors_are_one_clear_line_and_exit_2(args, message):
    res = invoke(*args)
    assert res.exit_code == 2
    assert message in res.output and "Traceback" not in res.output


def test_bad_parameter_value_is_a_clear_error(kitti_folder, tmp_path):
    res = invoke("run", "--dataset", str(kitti_folder), "--codec", "random",
                 "--param", "random.ratio=1.5", "--store", str(tmp_path / "x.sqlite"))
    assert res.exit_code == 2 and "above the maximum" in res.output


def test_inspect_payload_scan_and_store(tmp_path, store, kitti_folder, vlp16_frame):
    from lwbench.registry import get_registry

    payload = get_registry().codec("raw")().encode(vlp16_frame)
    (tmp_path / "p.lwb").write_bytes(payload)
    out = invoke("inspect", str(tmp_path / "p.lwb")).stdout
    assert "lwbench payload" in out and "57600" in out.replace(",", "")
    (tmp_path / "bad.lwb").write_bytes(payload[:-3])
    res = invoke("inspect", str(tmp_path / "bad.lwb"))
    assert res.exit_code == 2 and "checksum" in res.output
    assert "KITTI" in invoke("inspect", str(kitti_folder)).stdout.upper()
    assert "results store" in invoke("inspect", str(store)).stdout


def test_changed_data_under_the_same_label_is_not_averaged_in(tmp_path):
    import numpy as np

    from lwbench.results.leaderboard import build_leaderboard
    from lwbench.results.store import ResultRow, ResultStore

    with ResultStore(tmp_path / "r.sqlite") as store:
        for ds_id, value in (("sim:v1", 1.0), ("sim:v2", 3.0)):
            store.put(ResultRow("frame", "sim", ds_id, 0, "raw", "1", {}, "ok", {"bytes": value}, 0))
        entries = build_leaderboard(store)
    assert sorted(e.value("bytes") for e in entries) == [1.0, 3.0]
    assert len({e.dataset for e in entries}) == 2 and not np.isnan(entries[0].value("bytes"))


def test_unknown_metric_ids_are_refused_with_the_valid_ones(store):
    for args in (("--sort", "rmsd"), ("--columns", "bytes,foo")):
        res = invoke("leaderboard", "--store", str(store), *args)
        assert res.exit_code == 2 and "unknown metric id" in res.output and "range_rmsd" in res.output


def test_columns_are_honoured_in_every_format(store):
    table = invoke("leaderboard", "--store", str(store), "--columns", "bytes,coverage").stdout
    header = next(line for line in table.splitlines() if "codec" in line)
    assert "bytes" in header and "coverage" in header and "chamfer" not in header
    md = invoke("leaderboard", "--store", str(store), "--format", "md", "--columns", "chamfer").stdout
    assert "chamfer [m]" in md.splitlines()[0] and "bytes" not in md.splitlines()[0]


def test_the_run_prints_what_it_asked_for_not_the_whole_store(store, kitti_folder):
    res = invoke("run", "--dataset", str(kitti_folder), "--codec", "raw", "--frames", "1", "--store", str(store))
    assert res.exit_code == 0
    raw = next(line for line in res.stdout.splitlines() if line.split()[:1] == ["raw"])
    assert raw.split()[1] == "1"  # frames: the one frame this run asked for
    # The whole store's board pools all three frames of raw, and says that random saw others.
    board = json.loads(invoke("leaderboard", "--store", str(store), "--format", "json").stdout)
    assert {d["codec"]: d["frames"] for d in board}["raw"] == 3


@pytest.mark.heavy
def test_labels_spell_out_swept_defaults(tmp_path, kitti_folder):
    store = tmp_path / "sweep.sqlite"
    res = invoke("run", "--dataset", str(kitti_folder), "--codec", "random", "--param", "random.ratio=0.1,0.2",
                 "--frames", "1", "--store", str(store))
    assert res.exit_code == 0
    board = json.loads(invoke("leaderboard", "--store", str(store), "--format", "json").stdout)
    assert sorted(d["label"] for d in board) == ["random(ratio=0.1)", "random(ratio=0.2)"]


def test_a_narrow_terminal_leaves_columns_out_instead_of_folding_numbers(store, monkeypatch):
    import io

    from rich.console import Console

    from lwbench.cli import output
    from lwbench.registry import get_registry
    from lwbench.results.leaderboard import build_leaderboard
    from lwbench.results.store import ResultStore

    buf = io.StringIO()
    monkeypatch.setattr(output, "console", Console(file=buf, width=90))
    with ResultStore(store, readonly=True) as results:
        entries = build_leaderboard(results, info=get_registry().metric_info())
    output.print_board(entries, "ratio", None, get_registry().metric_info())
    out = buf.getvalue()
    assert "not shown (terminal too narrow)" in out
    assert all(len(line) <= 90 for line in out.splitlines())
    # No number is split across lines: every cell of the bytes column reads as one number.
    rows = [line for line in out.splitlines() if line.split()[:1] in (["raw"], ["random(ratio=0.1)"])]
    assert len(rows) == 2 and all(r.split()[2].replace(",", "").isdigit() for r in rows)


def test_version():
    res = invoke("--version")
    assert res.exit_code == 0 and res.stdout.startswith("lwbench ")


@pytest.mark.heavy
def test_a_missing_open3d_is_one_line_and_exit_2(tmp_path, kitti_folder):
    """With Open3D unimportable, a command that needs it fails with what to install, no traceback."""
    import os
    import subprocess
    import sys

    fake = tmp_path / "fake"
    (fake / "open3d").mkdir(parents=True)
    (fake / "open3d" / "__init__.py").write_text("raise ImportError('libusb-1.0.so.0: cannot open shared object file')")
    env = {**os.environ, "PYTHONPATH": str(fake)}
    script = "import sys; from lwbench.cli import main; sys.argv = ['lwbench', *sys.argv[1:]]; main()"
    res = subprocess.run(
        [sys.executable, "-c", script, "run", "--dataset", str(kitti_folder), "--codec", "raw",
         "--store", str(tmp_path / "s.sqlite")],
        env=env, capture_output=True, text=True,
    )
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "Open3D cannot be imported" in res.stderr
    assert "failed:" not in res.stdout + res.stderr  # an environment problem is not a codec's failure


@pytest.mark.heavy
def test_plugin_commands_load_lazily_and_their_errors_are_one_line(tmp_path):
    """Importing the CLI loads no plugin; a plugin command that raises an lwbench error gets the
    same one line and exit status 2 as a built-in one, and a broken hook leaves the others working."""
    import os
    import subprocess
    import sys

    (tmp_path / "cmd_plugin.py").write_text(
        "import lwbench\n"
        "@lwbench.hookimpl\n"
        "def lwbench_register_commands(cli):\n"
        "    @cli.command('shout')\n"
        "    def shout(dataset: str = 'nosuch-dataset') -> None:\n"
        "        lwbench.open_dataset(dataset)\n"
    )
    (tmp_path / "broken_cmd.py").write_text(
        "import lwbench\n"
        "@lwbench.hookimpl\n"
        "def lwbench_register_commands(cli):\n"
        "    raise RuntimeError('no commands today')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "LWBENCH_PLUGINS": "cmd_plugin,broken_cmd"}
    lazy = subprocess.run([sys.executable, "-c", "import sys, lwbench.cli; print('lwbench.registry' in sys.modules)"],
                          env=env, capture_output=True, text=True)
    assert lazy.stdout.strip() == "False"
    res = subprocess.run([sys.executable, "-m", "lwbench.cli", "shout"], env=env, capture_output=True, text=True)
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().startswith("error: unknown dataset 'nosuch-dataset'") and "Traceback" not in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    listing = subprocess.run([sys.executable, "-m", "lwbench.cli", "--help"], env=env, capture_output=True, text=True)
    assert listing.returncode == 0 and "shout" in listing.stdout and "Plugin commands" in listing.stdout


def test_frames_means_the_first_n_frames_everywhere(tmp_path):
    """``--frames N`` is the first N frames of the dataset in every command; the simulator, which
    generates 20 by default, is asked for more when more are wanted (not silently 20)."""
    from lwbench.registry import get_registry
    from lwbench.run import RunRequest

    reg = get_registry()
    (few,) = RunRequest.from_words(reg, codecs=["raw"], frames=3).plans(reg)
    (many,) = RunRequest.from_words(reg, codecs=["raw"], frames=30).plans(reg)
    assert "frames" not in few.dataset.params and few.frames == 3  # the default sequence, cut: cache hits stay
    assert many.dataset.params["frames"] == 30 and many.frames == 30
    (given,) = RunRequest.from_words(reg, codecs=["raw"], frames=30, dataset_params=["frames=25"]).plans(reg)
    assert given.dataset.params["frames"] == "25"  # the user's own setting wins
    res = invoke("simulate", "indoor", "--out", str(tmp_path / "sim"), "--frames", "2")
    assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "sim" / "velodyne").glob("*.bin"))) == 2
