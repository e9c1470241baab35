"""Progress for every phase: plain lines on stderr off a terminal (a line when a phase starts, at
most one per interval while it runs -- also when nothing finished, so a long item still shows
it is alive -- and one when it ends), stdout left to the command's result."""

from __future__ import annotations

import io
import json
import re
import time

import pytest
from typer.testing import CliRunner

from lwbench.cli import app
from lwbench.progress import Progress, format_duration

runner = CliRunner()


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_plain_lines_start_beat_at_most_once_an_interval_and_end():
    out, clock = io.StringIO(), Clock()
    with Progress(live=False, interval_s=10, stream=out, clock=clock, heartbeat=False) as shown:
        phase = shown.phase("frames", 4)
        clock.t = 1
        phase.update(1, what="last: raw frame 0", part="raw")  # < 10 s after the first line: quiet
        clock.t = 12
        phase.update(2, what="last: gmm frame 0", part="gmm")
        clock.t = 30
        shown.tick()  # nothing finished since: the heartbeat still says where it is
        clock.t = 31
        shown.tick()  # but not twice in one interval
        phase.finish()
    lines = out.getvalue().splitlines()
    assert lines == [
        "lwbench: frames 0/4 (0%) · 0s",
        "lwbench: frames 2/4 (50%) · 12s · eta 12s · raw 1, gmm 1 · last: gmm frame 0",
        "lwbench: frames 2/4 (50%) · 30s · eta 30s · raw 1, gmm 1 · last: gmm frame 0",
        "lwbench: frames done: 2/4 in 31s",
    ]


def test_a_phase_not_announced_waits_for_its_first_update_or_one_interval():
    out, clock = io.StringIO(), Clock()
    with Progress(live=False, interval_s=10, stream=out, clock=clock, heartbeat=False) as shown:
        quiet = shown.phase("frames", announce=False)
        clock.t = 5
        shown.tick()  # refused at once (a bad option found in the first second) prints only its error
        assert out.getvalue() == ""
        clock.t = 10
        shown.tick()
        assert out.getvalue() == "lwbench: frames 0 done · 10s\n"
        clock.t = 11
        quiet.update(1, total=2)
    assert out.getvalue().splitlines()[1:] == ["lwbench: frames done: 1/2 in 11s"]
    out = io.StringIO()
    with Progress(live=False, interval_s=10, stream=out, clock=Clock(), heartbeat=False) as shown:
        shown.phase("frames", announce=False)  # nothing to do (every row cached): nothing said
    assert out.getvalue() == ""


def test_the_heartbeat_runs_on_its_own_while_the_work_blocks():
    out = io.StringIO()
    with Progress(live=False, interval_s=0.05, stream=out) as shown:
        shown.phase("streaming raw through 50 KB/s")
        time.sleep(0.6)  # one long item: no update at all
    lines = out.getvalue().splitlines()
    assert len([x for x in lines if x.startswith("lwbench: streaming raw")]) >= 3
    assert lines[-1].startswith("lwbench: streaming raw through 50 KB/s done: 0 in ")


def test_durations_read_as_a_log_says_them():
    assert [format_duration(s) for s in (0.4, 59, 61, 3599, 3720)] == ["0s", "59s", "1m01s", "59m59s", "1h02m"]


def _phases(stderr: str) -> list[str]:
    return [line.split(" done:")[0].removeprefix("lwbench: ") for line in stderr.splitlines() if " done: " in line]


@pytest.mark.heavy
def test_run_reports_the_frames_and_the_sequence_metrics_off_a_terminal(tmp_path):
    # The simulator: it has poses, so the sequence metrics run after the frames.
    res = runner.invoke(app, ["run", "--frames", "3", "--codec", "raw", "--store", str(tmp_path / "r.sqlite")],
                        env={"LWBENCH_PROGRESS_S": "0"}, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert _phases(res.stderr) == ["frames (encode, decode, frame metrics)", "sequence metrics"]
    assert "last: raw frame 0" in res.stderr
    # Inside the sequence stage: which configuration, metric, pass and frame (issue 31).
    inside = re.findall(r"lwbench: sequence metrics \d+/3 .*· raw · (\w+) · ([\w ]+) (\d+)/3", res.stderr)
    assert {m for m, _, _ in inside} == {"localization", "odometry", "occupancy"}, res.stderr[-2000:]
    assert {"map", "tracking", "occupancy hits", "originals map"} <= {p for _, p, _ in inside}
    assert "lwbench:" not in res.stdout  # stdout is the board


def test_simulate_and_encode_report_their_phase(tmp_path):
    env = {"LWBENCH_PROGRESS_S": "0"}
    res = runner.invoke(app, ["simulate", "urban", "--frames", "2", "--out", str(tmp_path / "sim")], env=env,
                        catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "lwbench: simulating urban done: 2/2 in " in res.stderr and "scan 1" in res.stderr
    res = runner.invoke(app, ["encode", str(tmp_path / "sim"), "--codec", "raw", "--out", str(tmp_path / "enc")],
                        env=env, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "lwbench: encoding with raw done: 2/2 in " in res.stderr


@pytest.mark.heavy
def test_stream_reports_reading_and_each_stream(tmp_path):
    res = runner.invoke(app, ["stream", "--codec", "raw", "--frames", "2", "--out", str(tmp_path / "s")],
                        env={"LWBENCH_PROGRESS_S": "0"}, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    phases = _phases(res.stderr)
    assert phases[0].startswith("reading the 2 scans of sim") and phases[1] == "streaming raw through 50 KB/s"
    assert "lwbench: streaming raw through 50 KB/s done: 2/2 in " in res.stderr  # it counts (issue 33)
    (run,) = json.loads((tmp_path / "s" / "stream.json").read_text())["runs"]
    assert run["frames"] == 2


@pytest.mark.heavy
def test_report_config_opens_one_frames_phase_per_run_not_per_row(tmp_path):
    """Issue 33: `lwbench report --config` built a new progress phase on every stored row (20,272
    lines on the RD study). Two runs (two seeds) of three frames: two frames phases."""
    run_file = tmp_path / "study.toml"
    run_file.write_text(
        f'store = "{tmp_path / "r.sqlite"}"\nframes = 3\nseeds = [0, 1]\nsequence_metrics = false\n'
        '[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n[[codec]]\nname = "random"\n'
    )
    # A heartbeat every 0.3 s: every phase left open says "0 done" on each beat (140 lines before).
    # A plan's phase opens when the plan starts (a long first frame is reported, as `lwbench run`
    # does) and closes when it ends: it may say "0 done" before its first row, never after its end.
    res = runner.invoke(app, ["report", "--config", str(run_file), "--out", str(tmp_path / "rep")],
                        env={"LWBENCH_PROGRESS_S": "0.3"}, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    lines = [line for line in res.stderr.splitlines() if line.startswith("lwbench:")]
    assert len([line for line in lines if line.startswith("lwbench: frames") and " done: " in line]) == 2
    frame_lines = [line for line in lines if line.startswith("lwbench: frames")]
    assert " done: " in frame_lines[-1] and len(frame_lines) < 40, frame_lines[:5]
    # After the first plan's phase ended, its 6/6 never beats again (the second plan counts anew).
    first_end = next(i for i, line in enumerate(frame_lines) if " done: " in line)
    assert "6/6" not in frame_lines[first_end + 1], frame_lines
