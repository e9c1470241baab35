"""``lwbench fuzz`` (issue 34, item 5): the long campaigns of docs/hostile.md as a command, whose
exit status says whether a case broke the contract (CI gates on it)."""

from __future__ import annotations

import json
from collections import Counter

import pytest
from typer.testing import CliRunner

import lwbench.fuzz
from lwbench.cli import app
from lwbench.fuzz import FuzzReport

runner = CliRunner()


def test_a_short_campaign_on_two_codecs_counts_every_case(tmp_path):
    res = runner.invoke(app, ["fuzz", "raw", "rangeimage", "--cases", "12", "--format", "json",
                              "--out", str(tmp_path / "cases")], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    rows = {r["codec"]: r for r in json.loads(res.stdout)}
    assert sorted(rows) == ["rangeimage", "raw"]
    for r in rows.values():
        assert r["cases"] == 12 and r["other"] == 0 and r["broke"] == {}
        assert r["decoded"] + r["payload_errors"] == 12
    assert list((tmp_path / "cases").iterdir()) == []  # nothing broke: nothing written


def test_the_table_and_markdown_name_each_codec():
    res = runner.invoke(app, ["fuzz", "raw", "--cases", "4"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert "raw" in res.stdout and "PayloadError" in res.stdout
    res = runner.invoke(app, ["fuzz", "raw", "--cases", "4", "--format", "md"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    assert res.stdout.splitlines()[0].startswith("| codec | cases | decoded | PayloadError | other |")
    assert res.stdout.splitlines()[2].startswith("| raw | 4 |")


def test_a_codec_that_needs_more_than_a_scan_is_skipped_and_said_so():
    res = runner.invoke(app, ["fuzz", "oracle", "--cases", "4", "--format", "json"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    (row,) = json.loads(res.stdout)
    assert row["codec"] == "oracle" and "needs" in row["skipped"]


def test_an_escape_makes_the_exit_status_1_and_the_case_is_written(tmp_path, monkeypatch):
    def broken(codec_cls, params=None, **kwargs):
        report = FuzzReport(codec_cls.name, cases=3, outcomes=Counter(ok=1, PayloadError=1, ValueError=1),
                            verdicts=Counter(fine=2, ValueError=1))
        report.failures.append(("ValueError", "boom", b"LWB-case"))
        return report

    monkeypatch.setattr(lwbench.fuzz, "fuzz_codec", broken)
    res = runner.invoke(app, ["fuzz", "raw", "--cases", "3", "--out", str(tmp_path)], catch_exceptions=False)
    assert res.exit_code == 1, res.output
    assert "1 case(s) broke the contract" in " ".join(res.stderr.split())
    assert (tmp_path / "raw-0-ValueError.lwb").read_bytes() == b"LWB-case"


@pytest.mark.parametrize("args, says", [
    (["fuzz", "no-such-codec"], "unknown codec 'no-such-codec'"),
    (["fuzz", "raw", "rangeimage", "--param", "step=0.1"], "write CODEC.KEY=VALUE"),
    (["fuzz", "rangeimage", "--param", "rangeimage.step=abc"], "cannot read 'abc' as float"),
    (["fuzz", "raw", "--param", "rangeimage.step=0.1"], "not fuzzed here"),
    (["fuzz", "raw", "--format", "csv"], "--format 'csv'"),
])
def test_a_wrong_use_is_one_line_and_exit_status_2(args, says):
    res = runner.invoke(app, args, catch_exceptions=False)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, res.output
    assert len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], res.stderr


def test_settings_start_from_the_codecs_own_test_params():
    from lwbench.cli.fuzz import fuzz_settings
    from lwbench.registry import get_registry

    reg = get_registry()
    classes = {n: reg.codec(n) for n in ("vsgp", "rangeimage")}
    settings = fuzz_settings(classes, ["vsgp.residual=0.1"])
    assert settings["vsgp"] == {**classes["vsgp"].test_params(), "residual": 0.1}
    assert settings["rangeimage"] == classes["rangeimage"].test_params()
