"""``lwbench poconet-table`` (issue 34, item 5: tools/poconet_table.py became PocoNet's own
command, registered through ``lwbench_register_commands``). A real table takes minutes per seed;
here: its help, the Markdown it prints from leaderboard rows, and its wrong uses."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from lwbench.cli import app

runner = CliRunner()


def test_help_names_the_table_and_its_switches():
    res = runner.invoke(app, ["poconet-table", "--help"], env={"COLUMNS": "100"}, catch_exceptions=False)
    assert res.exit_code == 0, res.output
    for opt in ("--seeds", "--ratios", "--no-curve", "--no-controls", "--no-diagnose", "--from-store", "--store"):
        assert opt in res.stdout


def _row(name, seed, ate, codec=None):
    return {"row": name, "seed": seed, "codec": codec or name, "ate_rmse": ate, "rot_err_deg": 0.01,
            "map_points": 1000, "map_share": 0.05}


def test_the_table_pairs_each_method_with_random_seed_by_seed():
    from lwbench_plugins.poconet.table_command import table

    rows = [_row("random", 100, 0.03), _row("random", 101, 0.02), _row("poconet", 100, 0.01),
            _row("poconet", 101, 0.03), _row("raw", 100, 0.005), _row("sift3d", 100, 0.02), _row("sift3d", 101, 0.02)]
    text = table(rows, [100, 101]).splitlines()
    assert text[0].startswith("| method | ATE rmse (cm), seeds 100 / 101 |")
    by_name = {ln.split("|")[1].strip(): ln for ln in text[2:] if ln.startswith("| ")}
    assert list(by_name) == ["raw", "random", "sift3d", "poconet"]  # Table I's order
    assert "| -2.00 / +1.00 | 1/2 |" in by_name["poconet"]
    assert "| 0.50 / – |" in by_name["raw"]
    assert any(ln.startswith("Best keypoint selector: sift3d") for ln in text)


def test_rankings_are_paired_with_poconet_s_random_score_control():
    """Whether the scores earn their place: each ranking against the same rule with random order,
    per seed, with a sign test (5 of 5 wins: p = 1/32)."""
    from lwbench_plugins.poconet.table_command import CONTROL, table

    seeds = [100, 101, 102, 103, 104]
    rows = [_row(CONTROL, s, 0.02, "poconet") for s in seeds]
    rows += [_row("poconet", s, 0.01, "poconet") for s in seeds]
    rows += [_row("poconet, score=features' model (control)", s, 0.03 if s != 104 else 0.01, "poconet")
             for s in seeds]
    text = table(rows, seeds).splitlines()
    assert "| poconet | -1.00 / -1.00 / -1.00 / -1.00 / -1.00 | -1.00 | 5/5 | 0.031 |" in text
    feat = [ln for ln in text if ln.startswith("| poconet, score=features' model (control) | +1.00")]
    assert feat and feat[0].endswith("| 1/5 | 0.969 |")


def test_fractions_read_as_budgets():
    from lwbench_plugins.poconet.table_command import numbers

    assert numbers("1/12,1/24", "--ratios") == (1 / 12, 1 / 24)
    assert numbers("100,101", "--seeds", int) == (100, 101)


@pytest.mark.parametrize("args, says", [
    (["--seeds", "100,x"], "'x' is not an integer"),
    (["--ratios", "1/0"], "is not a number"),
    (["--seeds", ""], "at least one --seeds"),
    (["--from-store", "--store", "STORE"], "does not exist"),
])
def test_a_wrong_use_is_one_line_and_exit_status_2(tmp_path, args, says):
    args = [str(tmp_path / "none.sqlite") if a == "STORE" else a for a in args]
    res = runner.invoke(app, ["poconet-table", *args], catch_exceptions=False)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], res.stderr
