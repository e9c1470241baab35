"""``lwbench run --config``: a committed TOML file runs datasets x codecs x grids x seeds."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from lwbench.cli import app


def _invoke(*args: str):
    return CliRunner().invoke(app, list(args), catch_exceptions=False)


@pytest.mark.heavy
def test_a_run_file_runs_every_grid_point_and_seed(tmp_path, kitti_folder):
    store = tmp_path / "rd.sqlite"
    (tmp_path / "study.toml").write_text(f"""
store = "{store}"
frames = 2
seeds = [0, 1]

[[dataset]]
name = "{kitti_folder}"

[[codec]]
name = "raw"

[[codec]]
name = "random"
params = {{ ratio = [0.1, 0.3] }}
""")
    res = _invoke("run", "--config", str(tmp_path / "study.toml"))
    assert res.exit_code == 0, res.output
    board = json.loads(_invoke("leaderboard", "--store", str(store), "--format", "json").stdout)
    configs = sorted((d["codec"], d["params"].get("ratio"), d["params"].get("seed")) for d in board)
    assert configs == [("random", 0.1, 0), ("random", 0.1, 1), ("random", 0.3, 0), ("random", 0.3, 1),
                       ("raw", None, None)]
    assert all(d["frames"] == 2 for d in board if d["codec"] == "random")


def test_a_run_file_with_an_unknown_key_is_refused(tmp_path):
    (tmp_path / "bad.toml").write_text('frame = 3\n[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n')
    res = _invoke("run", "--config", str(tmp_path / "bad.toml"))
    assert res.exit_code == 2 and "unknown key(s) frame" in res.output and "frames" in res.output


def test_the_shipped_study_file_plans(tmp_path):
    from pathlib import Path

    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    study = Path(__file__).resolve().parents[1] / "examples" / "runs" / "rd_tunnel.toml"
    (plan,) = read_run_file(study).plans(get_registry())
    assert len(plan.configs) == 1 + 4 + 8 + 5 + 5 + 4 + 4 + 3 * 4
