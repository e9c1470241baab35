"""``lwbench rd`` says exactly why a BD-rate is missing (which configurations a guard took off the
curve, with the figure and the limit), takes ``--min-coverage`` like the leaderboard, computes the
BD-rate even where only the BD-distortion's range is missing, and prints rates, not log10(rates)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import pytest
from typer.testing import CliRunner

from lwbench.cli import app
from lwbench.registry import get_registry
from lwbench.results.rd import curves_from_entries, summarise


@dataclass
class Entry:
    """The part of a leaderboard entry the curves read."""

    codec: str
    label: str
    values: dict
    flags: list = field(default_factory=list)
    dataset: str = "tunnel"

    def shown(self, metric):
        return self.values.get(metric)

    def value(self, metric):
        return self.values.get(metric)


def _entries(codec, rates, rmsd, coverage):
    return [
        Entry(codec, f"{codec}({i})", {"bytes": r, "range_rmsd": d, "coverage": c},
              ["low_coverage"] if c < 0.9 else [])
        for i, (r, d, c) in enumerate(zip(rates, rmsd, coverage, strict=True))
    ]


INFO = get_registry().metric_info()
FINE = _entries("fine", [5e4, 7e4, 1e5, 1.4e5, 2e5], [3e-3, 1.5e-3, 7e-4, 3.4e-4, 8.5e-5], [0.7, 0.89, 1, 1, 1])
COARSE = _entries("coarse", [5e3, 8e3, 1.4e4, 2e4, 2.6e4], [2.9e-2, 1.4e-2, 5.8e-3, 2.9e-3, 1.4e-3], [1] * 5)


def _bd(min_coverage=None):
    limits = {} if min_coverage is None else {"min_coverage": min_coverage}
    entries = FINE + COARSE
    if min_coverage is not None:  # the board re-flags with the new limit
        entries = [Entry(e.codec, e.label, e.values, [f for f in e.flags if e.values["coverage"] < min_coverage])
                   for e in entries]
    left_out: list = []
    curves = curves_from_entries(entries, "range_rmsd", rate="bytes", info=INFO, left_out=left_out, limits=limits)
    summary = summarise(curves, unit="m", reference="fine", left_out=left_out, rate_unit="B")
    return summary["tunnel"]["bd"]["coarse"], left_out


def test_a_short_reference_curve_names_what_was_left_out_and_why():
    bd, left_out = _bd()
    assert len(left_out) == 2
    assert "fine on tunnel: 3 efficient point(s)" in bd["error"] and "at least 4" in bd["error"]
    assert "fine(0) (low_coverage: coverage 0.7 < 0.9; --min-coverage sets the limit)" in bd["error"]
    assert "fine(1) (low_coverage: coverage 0.89 < 0.9" in bd["error"]


def test_min_coverage_puts_the_points_back_and_the_bd_rate_exists_without_a_rate_overlap():
    bd, left_out = _bd(min_coverage=0.5)
    assert left_out == []
    # The coarse codec needs fewer bytes at the same quality where the two overlap (~55-57 dB).
    assert bd["bd_rate_pct"] < 0
    assert "bd_distortion" not in bd
    # The rate ranges are bytes with their unit, never log10(bytes).
    assert "do not overlap in rate (reference 50,000 B..200,000 B vs 5,000 B..26,000 B)" in bd["bd_distortion_error"]


@pytest.fixture(scope="module")
def store(tmp_path_factory, kitti_folder):
    path = tmp_path_factory.mktemp("rdcov") / "r.sqlite"
    res = CliRunner().invoke(app, [
        "run", "--dataset", str(kitti_folder), "--codec", "random", "--param", "random.ratio=0.6,0.7,0.8,0.95",
        "--store", str(path), "--no-sequence-metrics"], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return path


@pytest.mark.heavy
def test_rd_takes_min_coverage(store):
    def rd(*extra):
        res = CliRunner().invoke(app, ["rd", "--store", str(store), "--distortion", "range_rmsd", "--format", "json",
                                       *extra], catch_exceptions=False)
        assert res.exit_code == 0, res.output
        return json.loads(res.stdout)

    default, lowered = rd(), rd("--min-coverage", "0.5")
    assert len(default["left_out"]) == 3 and all("coverage" in s["reason"] for s in default["left_out"])
    assert lowered["left_out"] == []
    (curves,) = [d["curves"] for d in lowered["datasets"].values()]
    assert curves["random"]  # on the curve now (its efficient part: selection keeps exact points)
