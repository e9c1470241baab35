"""Suites (issue 35): protocols shipped with lwbench, identified by name, version and content
hash; every row a suite asks for says so, through export and import too."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

import lwbench.suites as suites
from lwbench.cli import app
from lwbench.registry import get_registry
from lwbench.results.bundle import export_bundle, import_bundle
from lwbench.results.store import ResultStore
from lwbench.run import RunRequest


def test_every_shipped_suite_plans_against_the_installed_plugins():
    names = {s.name for s in suites.list_suites()}
    assert {"sim-tunnel-1", "sim-urban-1", "sim-town-1"} <= names
    for s in suites.list_suites():
        assert s.id.startswith(s.name + "+") and len(s.id) == len(s.name) + 13
        plans = s.request().plans(get_registry())
        assert plans and all(p.configs for p in plans) and s.description


def test_sim_tunnel_1_asks_for_exactly_the_rows_of_the_default_run():
    """What makes `lwbench suite run sim-tunnel-1` print the README's main board (`lwbench run`):
    the same dataset identity, configurations, frames, seed and metrics -- the same keys."""
    reg = get_registry()
    (default,) = RunRequest().plans(reg)
    (suite,) = suites.find_suite("sim-tunnel-1").request().plans(reg)
    assert sorted(c.key for c in suite.configs) == sorted(c.key for c in default.configs)
    assert (suite.seed, suite.frames, suite.sequence_metrics, suite.metrics) == \
        (default.seed, default.frames, default.sequence_metrics, default.metrics)
    assert suite.dataset.build(reg).identity() == default.dataset.build(reg).identity()


def test_an_unknown_suite_names_the_known_ones():
    res = CliRunner().invoke(app, ["suite", "run", "sim-nowhere-9"])
    assert res.exit_code == 2 and "sim-tunnel-1" in res.output


@pytest.fixture
def tiny_suites(tmp_path, monkeypatch):
    folder = tmp_path / "suites"
    folder.mkdir()
    (folder / "tiny-1.toml").write_text(
        '# tiny-1: two codecs on two simulated tunnel scans.\nsequence_metrics = false\n'
        '[[dataset]]\nname = "sim"\nparams = { scene = "tunnel", frames = 2 }\n'
        '[[codec]]\nname = "raw"\n[[codec]]\nname = "random"\n')
    monkeypatch.setattr(suites, "SUITES_DIR", folder)
    return folder


def test_a_suite_run_tags_its_rows_cached_ones_too_and_the_tags_travel(tiny_suites, tmp_path):
    runner = CliRunner()
    store = tmp_path / "s.sqlite"
    plain = runner.invoke(app, ["run", "--dataset", "sim", "--dataset-param", "frames=2", "--codec", "raw",
                                "--no-sequence-metrics", "--store", str(store)], catch_exceptions=False)
    assert plain.exit_code == 0
    res = runner.invoke(app, ["suite", "run", "tiny-1", "--store", str(store)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "cached 2 of 4" in " ".join(res.stdout.split())  # raw's rows were already there
    (suite,) = suites.list_suites()
    with ResultStore(store, readonly=True) as results:
        tags = results.suites_of()
        assert len(tags) == 4 and all(v == [suite.id] for v in tags.values())
        export_bundle(results, tmp_path / "b.jsonl")
    board = runner.invoke(app, ["leaderboard", "--store", str(store), "--suite", "tiny-1", "--format", "json"])
    assert sorted(e["codec"] for e in json.loads(board.stdout)) == ["random", "raw"]
    with ResultStore(tmp_path / "team.sqlite") as team:
        import_bundle(tmp_path / "b.jsonl", team)
        assert set(map(tuple, team.suites_of().values())) == {(suite.id,)}
    # An edited suite is another suite, whatever its name.
    (tiny_suites / "tiny-1.toml").write_text((tiny_suites / "tiny-1.toml").read_text() + "seeds = [0]\n")
    assert suites.find_suite("tiny-1").id != suite.id
