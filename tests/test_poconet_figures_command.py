"""``lwbench poconet-ablation`` and ``lwbench poconet-real`` (issue 34, item 5: were
tools/poconet_ablation.py and tools/poconet_real.py, which imported the plugin's internals; now
PocoNet's own commands). The ablation needs poconet-table's labels (minutes to make): its wrong
uses here; the real-scan table runs on a small folder."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from lwbench.cli import app

runner = CliRunner()


def test_the_real_scan_table_on_a_small_folder(kitti_folder, tmp_path):
    res = runner.invoke(app, ["poconet-real", str(kitti_folder), "--png", str(tmp_path)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    (row,) = [ln for ln in res.stdout.splitlines() if ln.startswith(f"| {kitti_folder.name} |")]
    cells = [c.strip() for c in row.split("|")[1:-1]]
    assert cells[2] == cells[3]  # exactly the budget is kept
    assert (tmp_path / f"poconet_{kitti_folder.name}.png").stat().st_size > 0


@pytest.mark.parametrize("args, says", [
    (["poconet-real", "SCANS", "--ratio", "0.1,0.2"], "one share of the scan"),
    (["poconet-real", "SCANS", "--ratio", "2"], "one share of the scan"),
    (["poconet-ablation", "--labels-root", "NOLABELS"], "no labels at"),
    (["poconet-ablation", "--seeds", "100", "--frames", "10"], "at least two scans"),
    (["poconet-ablation", "--frames", "ten"], "'ten' is not an integer"),
])
def test_a_wrong_use_is_one_line_and_exit_status_2(kitti_folder, tmp_path, args, says):
    args = [str(kitti_folder) if a == "SCANS" else str(tmp_path) if a == "NOLABELS" else a for a in args]
    res = runner.invoke(app, args, catch_exceptions=False)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], res.stderr


def test_help_of_both():
    for command in ("poconet-ablation", "poconet-real"):
        res = runner.invoke(app, [command, "--help"], catch_exceptions=False)
        assert res.exit_code == 0 and "--weights" in res.stdout
