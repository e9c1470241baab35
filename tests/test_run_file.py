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


def test_a_codec_named_twice_runs_the_union_of_its_grids_and_a_dataset_sets_its_frames(tmp_path):
    """Issue 34, item 4: what tools/codecs_rd.sh looped over `lwbench run` for -- rangeimage's
    step swept and its lossless mode with both refine settings, one dataset at 5 frames and
    another at 1 -- is one run file."""
    from lwbench.registry import get_registry
    from lwbench.run.config import read_run_file

    path = tmp_path / "rd.toml"
    path.write_text(
        '[[dataset]]\nname = "sim"\nparams = { scene = "tunnel" }\nframes = 5\n'
        '[[dataset]]\nname = "sim"\nparams = { scene = "urban" }\nframes = 1\n'
        '[[codec]]\nname = "rangeimage"\nparams = { step = [0.05, 0.02] }\n'
        '[[codec]]\nname = "rangeimage"\nparams = { mode = "lossless", refine = ["beam", "none"] }\n'
        '[[codec]]\nname = "raw"\n'
    )
    tunnel, urban = read_run_file(path).plans(get_registry())
    assert (tunnel.frames, urban.frames) == (5, 1)
    ri = [c.params for c in tunnel.configs if c.name == "rangeimage"]
    assert sorted(p["step"] for p in ri if p["mode"] != "lossless") == [0.02, 0.05]
    assert sorted(p["refine"] for p in ri if p["mode"] == "lossless") == ["beam", "none"]
    assert len(ri) == 4 and [c.name for c in tunnel.configs].count("raw") == 1


def test_a_dataset_frames_that_is_not_a_positive_integer_is_refused(tmp_path):
    from lwbench.errors import ParameterError
    from lwbench.run.config import read_run_file

    path = tmp_path / "bad.toml"
    path.write_text('[[dataset]]\nname = "sim"\nframes = 0\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match="frames must be a positive integer"):
        read_run_file(path)
