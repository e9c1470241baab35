"""Issue 35: results from many machines on one board. Two stores made "on two machines" (two
labels, two thread budgets) export, import and meet on one board, rd and report; the store
carries its metric declarations, so a board reads the same where a metric plugin is missing;
runtimes travel as multiples of each machine's reference workload (``encode_x``)."""

from __future__ import annotations

import gzip
import json

import pytest
from typer.testing import CliRunner

from lwbench.cli import app
from lwbench.errors import StoreError
from lwbench.registry import get_registry
from lwbench.results.bundle import export_bundle, import_bundle, open_results, read_bundle
from lwbench.results.leaderboard import board_info, build_leaderboard
from lwbench.results.store import ResultStore
from lwbench.run import DatasetRequest, RunRequest, Study

CODECS = ("raw", "random", "rangeimage")


def _run(path, machine: str) -> None:
    request = RunRequest(datasets=(DatasetRequest("sim", {"scene": "tunnel"}, frames=2),), codecs=CODECS,
                         sweeps={"random": {"ratio": [0.05]}}, sequence_metrics=False, isolate=False, store=path,
                         machine=machine)
    Study.prepare(request, get_registry()).run()


@pytest.fixture(scope="module")
def two_machines(tmp_path_factory):
    root = tmp_path_factory.mktemp("machines")
    _run(root / "alpha.sqlite", "alpha")
    _run(root / "beta.sqlite", "beta")
    with ResultStore(root / "alpha.sqlite", readonly=True) as a:
        export_bundle(a, root / "alpha.jsonl.gz")
    with ResultStore(root / "beta.sqlite", readonly=True) as b:
        export_bundle(b, root / "beta.jsonl")
    return root


def _board(results, **kw):
    return build_leaderboard(results, info=board_info(results, get_registry().metric_declarations()), **kw)


def test_two_machines_meet_on_one_board_quality_once_runtimes_each(two_machines):
    with ResultStore(two_machines / "team.sqlite") as team:
        assert import_bundle(two_machines / "alpha.jsonl.gz", team) == 6
        assert import_bundle(two_machines / "beta.jsonl", team) == 6
        assert team.count() == 0  # imported rows are never this machine's cache
        pooled = _board(team)
        split = _board(team, by_machine=True)
    with ResultStore(two_machines / "alpha.sqlite", readonly=True) as alpha:
        alone = {e.label: e for e in _board(alpha)}
    assert len(pooled) == 3 and len(split) == 6
    for e in pooled:
        assert e.machines == ("alpha", "beta") and e.frames == 2
        # quality: each key once -- the same values as one machine's board
        for metric in ("bytes", "range_rmsd", "coverage"):
            assert e.value(metric) == pytest.approx(alone[e.label].value(metric))
        assert e.value("encode_x") is not None and e.value("encode_x") > 0
    assert sorted(e.label for e in split) == sorted(f"{lab} @{m}" for lab in alone for m in ("alpha", "beta"))


def test_encode_x_is_encode_ms_over_the_rows_reference(two_machines):
    with ResultStore(two_machines / "alpha.sqlite", readonly=True) as alpha:
        rows = [r for r in alpha.rows() if r.status == "ok"]
        (raw,) = [e for e in _board(alpha) if e.codec == "raw"]
    assert all(r.extra["reference_ms"] > 0 for r in rows)
    expected = [r.metrics["encode_ms"] / r.extra["reference_ms"] for r in rows if r.codec == "raw"]
    assert raw.value("encode_x") == pytest.approx(sum(expected) / len(expected))


def test_the_cli_puts_stores_and_bundles_on_one_board_rd_and_report(two_machines, tmp_path):
    runner = CliRunner()
    sources = ["--store", str(two_machines / "alpha.jsonl.gz"), "--store", str(two_machines / "beta.sqlite")]
    res = runner.invoke(app, ["leaderboard", *sources, "--format", "json", "--by-machine"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    board = json.loads(res.stdout)
    assert sorted(b["machines"][0] for b in board) == ["alpha"] * 3 + ["beta"] * 3
    res = runner.invoke(app, ["leaderboard", *sources, "--columns", "bytes,encode_ms,encode_x"],
                        catch_exceptions=False, env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "encode_x" in res.stdout
    res = runner.invoke(app, ["rd", *sources, "--format", "json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    rd = json.loads(res.stdout)
    assert rd["distortion"] == "range_rmsd" and rd["rate"] == "bytes" and rd["datasets"]
    res = runner.invoke(app, ["report", *sources, "--out", str(tmp_path / "rep")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "Machines: alpha, beta" in page and "@alpha" in page and "@beta" in page
    res = runner.invoke(app, ["export", str(tmp_path / "again.jsonl"), "--store", str(two_machines / "alpha.sqlite")])
    assert res.exit_code == 0 and read_bundle(tmp_path / "again.jsonl").header["machines"].keys() == {"alpha"}
    res = runner.invoke(app, ["import", str(tmp_path / "again.jsonl"), "--store", str(tmp_path / "t.sqlite")])
    assert res.exit_code == 0 and "imported 6 row(s)" in res.stdout


def test_a_damaged_bundle_is_refused_whole(two_machines, tmp_path):
    lines = (two_machines / "beta.jsonl").read_text().splitlines(keepends=True)
    (tmp_path / "cut.jsonl").write_text("".join(lines[:-2]))
    with pytest.raises(StoreError, match="truncated"):
        read_bundle(tmp_path / "cut.jsonl")
    row = json.loads(lines[1])
    row["row"]["metrics"]["bytes"] = 1.0  # a better figure, written by hand
    (tmp_path / "edited.jsonl").write_text(lines[0] + json.dumps(row) + "\n" + "".join(lines[2:]))
    with pytest.raises(StoreError, match="checksum"):
        read_bundle(tmp_path / "edited.jsonl")
    row["row"]["params"] = {"ratio": 0.5}  # and a configuration it was not
    (tmp_path / "forged.jsonl").write_text(lines[0] + json.dumps(row) + "\n" + "".join(lines[2:]))
    with pytest.raises(StoreError, match="key"):
        read_bundle(tmp_path / "forged.jsonl")
    with gzip.open(tmp_path / "junk.jsonl.gz", "wt") as fh:
        fh.write('{"kind": "something else"}\n')
    with pytest.raises(StoreError, match="not an lwbench bundle"):
        read_bundle(tmp_path / "junk.jsonl.gz")
    with ResultStore(tmp_path / "s.sqlite") as s:
        with pytest.raises(StoreError):
            import_bundle(tmp_path / "cut.jsonl", s)
        assert list(s.rows()) == []  # nothing of a bad bundle is written


def test_a_store_ranks_and_flags_the_same_with_a_metric_plugin_uninstalled(two_machines):
    """The store carries its metrics' declarations: with the range metric (coverage guard,
    range_rmsd's direction) uninstalled, the board has the same order and flags."""
    installed = get_registry().metric_declarations()
    without = [d for d in installed if d["name"] != "ranges"]
    assert len(without) == len(installed) - 1
    with ResultStore(two_machines / "alpha.sqlite", readonly=True) as alpha:
        def board(declarations, sort):
            entries = build_leaderboard(alpha, info=board_info(alpha, declarations), sort=sort)
            return [(e.label, tuple(e.flags)) for e in entries]

        for sort in ("coverage", "range_rmsd", "ratio"):
            assert board(without, sort) == board(installed, sort)
        assert any("low_coverage" in f for _, f in board(without, "ratio"))  # random keeps 5 %
        # Without the store's declarations (a store of an older lwbench), the flag is lost:
        # what the test guards against.
        bare = build_leaderboard(alpha, info=board_info(None, without), sort="ratio")
        assert not any("low_coverage" in e.flags for e in bare)


def test_open_results_of_one_store_reads_it_in_place(two_machines):
    with open_results([two_machines / "alpha.sqlite"]) as one:
        assert one.readonly and one.count() == 6
