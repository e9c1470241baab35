"""The documented plugin example, installed as a real package, is found through its entry
point and runs -- the path every third-party codec takes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "lwbench-example-codec"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    target = tmp_path_factory.mktemp("site")
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
         "--target", str(target), str(EXAMPLE)],
        check=True, capture_output=True,
    )
    return target


def _lwbench(target: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(target)}
    return subprocess.run([sys.executable, "-m", "lwbench.cli", *args], env=env, capture_output=True, text=True)


@pytest.mark.heavy
def test_example_plugin_is_listed_with_its_provider(installed):
    res = _lwbench(installed, "list", "--json")
    assert res.returncode == 0, res.stderr
    codecs = {c["name"]: c for c in json.loads(res.stdout)["codecs"]}
    assert "half" in codecs
    assert codecs["half"]["provider"].startswith("lwbench-example-codec")


@pytest.mark.heavy
def test_example_plugin_runs_and_lands_on_the_leaderboard(installed, tmp_path, kitti_folder):
    store = tmp_path / "r.sqlite"
    res = _lwbench(installed, "run", "--dataset", str(kitti_folder), "--codec", "half",
                   "--codec", "raw", "--store", str(store))
    assert res.returncode == 0, res.stderr
    board = json.loads(_lwbench(installed, "leaderboard", "--store", str(store), "--format", "json").stdout)
    half = next(d for d in board if d["codec"] == "half")
    assert half["failures"] == 0
    assert 1.9 < half["ratio"] < 2.0  # 6 bytes per point instead of 12, plus the header
    assert half["chamfer"] < 0.01


@pytest.mark.heavy
def test_the_example_plugins_own_tests_pass_with_lwbenchs_conformance_kit(installed):
    """A third-party package runs lwbench.testing.check_codec in its own test suite."""
    env = {**os.environ, "PYTHONPATH": str(installed)}
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:dash", "-p", "no:cacheprovider", str(EXAMPLE / "tests")],
        env=env, capture_output=True, text=True, cwd=EXAMPLE,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert " passed" in res.stdout
