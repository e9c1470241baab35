"""``lwbench vsgp-bench`` (issue 34, item 5: tools/vsgp_realtime.py became VSGP's own command,
registered through ``lwbench_register_commands``): its subcommands, a real table on two small
scans, and its wrong uses as one line and exit status 2."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import CodecKind, Evaluation, codec_class, frame_metric
from lwbench.cli import app

runner = CliRunner()
SUBCOMMANDS = ("speed", "table", "rd", "warm", "threshold", "errors")


def test_help_lists_every_figure():
    res = runner.invoke(app, ["vsgp-bench", "--help"], env={"COLUMNS": "100"}, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    for name in SUBCOMMANDS:
        assert name in res.stdout
    for name in SUBCOMMANDS:
        res = runner.invoke(app, ["vsgp-bench", name, "--help"], catch_exceptions=False)
        assert res.exit_code == 0 and "--frames" in res.stdout and "--param" in res.stdout


def test_errors_table_on_a_small_folder_matches_the_range_metric(kitti_folder):
    res = runner.invoke(app, ["vsgp-bench", "errors", str(kitti_folder), "--frames", "1",
                              "--param", "num_inducing=100"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith("| 0 |")]
    assert len(lines) == 1, res.stdout
    rmsd_cm = float(lines[0].split("|")[3])
    # The same pairs as the run's range metric: its RMSD is the metric's range_rmsd.
    from lwbench import open_dataset

    frame = open_dataset(str(kitti_folder))[0]
    codec = codec_class("vsgp")(num_inducing=100, device="cpu")
    decoded = codec.decode(codec.encode(frame))
    ev = Evaluation(frame, b"", decoded, CodecKind.REPRESENTATION, {})
    metric = frame_metric("ranges")
    diff = metric.range_differences(ev)
    assert np.sqrt(np.mean(diff**2)) == pytest.approx(metric.compute(ev)["range_rmsd"])
    assert rmsd_cm == pytest.approx(100 * metric.compute(ev)["range_rmsd"], abs=0.06)


@pytest.mark.parametrize("args, says", [
    (["table", "DATA", "--m", "100,abc"], "--m '100,abc'"),
    (["rd", "DATA"], "at least one --vsgp"),
    (["rd", "DATA", "--vsgp", "num_inducing"], "expected KEY=V1"),
    (["errors", "DATA", "--param", "num_inducing"], "expected KEY=VALUE"),
    (["errors", "DATA", "--param", "no_such=1"], "unknown parameter"),
    (["speed", "DATA", "--setting", "old:num_inducing=100"], "no package vsgp_old"),
])
def test_a_wrong_use_is_one_line_and_exit_status_2(kitti_folder, args, says):
    args = [str(kitti_folder) if a == "DATA" else a for a in args]
    res = runner.invoke(app, ["vsgp-bench", *args, "--frames", "1"], catch_exceptions=False)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], res.stderr


def test_frame_metric_is_public_and_names_what_is_installed():
    from lwbench import PluginError

    assert frame_metric("ranges").name == "ranges"
    with pytest.raises(PluginError, match="no frame metric 'nope'"):
        frame_metric("nope")
