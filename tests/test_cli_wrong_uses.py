"""Every wrong use a new user tried (issue 23) gives one line on stderr and exit status 2 -- no
traceback, no five-line box -- and an unwritable output is refused before any work."""

from __future__ import annotations

import importlib.util
import re

import pytest
from typer.main import get_command
from typer.testing import CliRunner

from lwbench.cli import app

runner = CliRunner()


def wrong(*args: str, **kwargs):
    """Run a wrong use: exit 2, nothing on stdout but what came before, one line on stderr."""
    res = runner.invoke(app, list(args), catch_exceptions=False, **kwargs)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, (res.exit_code, res.output)
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("error: ") and "Traceback" not in res.output
    return lines[0]


@pytest.fixture(scope="module")
def store(tmp_path_factory, kitti_folder):
    path = tmp_path_factory.mktemp("wrong") / "r.sqlite"
    res = runner.invoke(app, ["run", "--dataset", str(kitti_folder), "--codec", "raw", "--store", str(path),
                              "--no-sequence-metrics"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return path


@pytest.mark.parametrize("args, says", [
    (("run", "--frames", "0"), "--frames"),
    (("run", "--workers", "0"), "--workers"),
    (("run", "--timeout", "-1"), "--timeout"),
    (("run", "--workers", "two"), "--workers"),
    (("run", "--nosuch"), "No such option: --nosuch"),
    (("nosuchcommand",), "No such command"),
    (("encode", "--codec", "raw"), "Missing argument"),
    (("stream", "--frames", "0"), "--frames"),
])
def test_a_usage_error_is_one_line_naming_the_help(args, says):
    line = wrong(*args)
    assert says in line
    assert "--help" in line and "╭" not in line


@pytest.mark.parametrize("args", [
    ("simulate", "urban", "--frames", "2", "--out", "/proc/lwbench-nope"),
    ("encode", "sim", "--codec", "raw", "--frames", "2", "--out", "/proc/lwbench-nope"),
    ("stream", "--codec", "raw", "--frames", "2", "--out", "/proc/lwbench-nope"),
    ("report", "--out", "/proc/lwbench-nope"),
])
def test_an_unwritable_out_is_refused_before_any_work(args):
    line = wrong(*args)
    assert "--out /proc/lwbench-nope: cannot create the folder" in line


def test_an_out_that_is_a_file_is_refused_before_the_stream(tmp_path):
    (tmp_path / "taken").write_text("")
    res = runner.invoke(app, ["stream", "--codec", "raw", "--frames", "2", "--out", str(tmp_path / "taken")])
    assert res.exit_code == 2 and "exists and is not a folder" in res.stderr
    assert "streaming" not in res.stdout  # refused before the study started


def test_the_out_folder_is_created_and_kept(tmp_path, kitti_folder):
    out = tmp_path / "a" / "b"
    res = runner.invoke(app, ["encode", str(kitti_folder), "--codec", "raw", "--frames", "1", "--out", str(out)],
                        catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert sorted(p.suffix for p in out.iterdir()) == [".json", ".lwb"]  # no probe file left behind


@pytest.mark.heavy
def test_conflicting_run_options_are_refused(store):
    line = wrong("run", "--in-process", "--workers", "2", "--codec", "raw", "--store", str(store))
    assert "--in-process" in line and "--workers 2" in line
    line = wrong("run", "--address", "auto", "--codec", "raw", "--store", str(store))
    assert "--executor ray" in line


def test_an_unknown_rd_reference_is_refused(store):
    line = wrong("rd", "--reference", "nosuch", "--store", str(store))
    assert "nosuch" in line and "stored: raw" in line


@pytest.mark.parametrize("columns", ["bytes,,ratio", "bytes,", ",ratio"])
def test_an_empty_column_id_is_refused(store, columns):
    assert "empty metric id" in wrong("leaderboard", "--columns", columns, "--store", str(store))


def test_an_unknown_sort_is_refused_before_the_evaluation(tmp_path):
    line = wrong("run", "--codec", "raw", "--frames", "1", "--sort", "nosuch", "--store", str(tmp_path / "s.sqlite"))
    assert "--sort" in line
    assert not (tmp_path / "s.sqlite").exists()  # nothing was evaluated


def test_a_codec_that_cannot_run_as_configured_is_refused_before_any_work(tmp_path):
    """The oracle without labels failed every frame of every set (issue 32): now one line."""
    line = wrong("run", "--codec", "oracle", "--frames", "1", "--store", str(tmp_path / "s.sqlite"))
    assert "oracle.labels=DIR" in line
    assert not (tmp_path / "s.sqlite").exists()


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None, reason="Ray is installed here")
def test_the_ray_hint_keeps_its_brackets(tmp_path):
    line = wrong("run", "--executor", "ray", "--codec", "raw", "--frames", "1", "--store", str(tmp_path / "s.sqlite"))
    assert "pip install 'lwbench[ray]'" in line


GROUP = get_command(app)


def _commands() -> list[str]:
    """lwbench's commands and the installed plugins' (vsgp, poconet ...)."""
    return GROUP.list_commands(GROUP.make_context("lwbench", ["--help"], resilient_parsing=True))


@pytest.mark.parametrize("command", _commands())
def test_help_at_80_columns_shows_every_option_whole(command):
    res = runner.invoke(app, [command, "--help"], env={"COLUMNS": "80"}, catch_exceptions=False)
    assert res.exit_code == 0
    assert max(len(line) for line in res.stdout.splitlines()) <= 80
    assert "…" not in res.stdout, res.stdout
    params = GROUP.commands[command].params
    shown = [p for p in params if not getattr(p, "hidden", False)]
    for opt in (o for p in shown for o in (*p.opts, *getattr(p, "secondary_opts", ())) if o.startswith("--")):
        assert re.search(rf"{re.escape(opt)}(?![\w-])", res.stdout), (opt, res.stdout)


def test_lwbench_alone_prints_the_help_once():
    res = runner.invoke(app, [], catch_exceptions=False)
    assert res.exit_code == 2 and res.output.count("Usage: ") == 1
    assert not any(line.startswith("error:") for line in res.output.splitlines())


@pytest.mark.heavy
@pytest.mark.parametrize("inside", [False, True], ids=["folder", "velodyne"])
def test_sequence_metrics_skipped_for_want_of_poses_say_so(tmp_path, kitti_folder, inside):
    """Issue 33: a folder without poses (or its velodyne/ folder) ran without its sequence metrics
    and said nothing. Now one note names the metrics and where poses would come from."""
    target = kitti_folder / "velodyne" if inside else kitti_folder
    res = runner.invoke(app, ["run", "--dataset", str(target), "--codec", "raw", "--frames", "1",
                              "--store", str(tmp_path / "r.sqlite")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    note = " ".join(res.stderr.split())
    assert "sequence metrics (localization, occupancy, odometry) skipped:" in note
    assert ("point at its parent" in note) == inside and ("no poses file" in note) != inside
