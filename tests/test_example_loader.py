"""The documented loader example (issue 34, item 3): a third-party loader derives its sensor
model and flags a guess through the public API only, and a study on it scores rows flagged
``sensor guessed`` -- as the built-in file loaders' are."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import _import_graph as graph_tool
import numpy as np
import pytest

from lwbench import DataWarning, get_sensor
from lwbench.registry import new_registry
from lwbench.results.leaderboard import build_leaderboard
from lwbench.results.store import ResultStore
from lwbench.run import DatasetRequest, RunRequest, Study
from lwbench.run.plan import resolve_dataset
from lwbench.testing import room_scan

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "lwbench-example-loader"
SENSOR = get_sensor("vlp16")


@pytest.fixture
def example(monkeypatch):
    """The example module importable (as after ``pip install -e``) and a registry of the installed
    plugins plus it, registered by module name as ``LWBENCH_PLUGINS`` would."""
    monkeypatch.syspath_prepend(str(EXAMPLE))
    import lwbench_example_loader

    registry = new_registry()
    assert registry.register_module("lwbench_example_loader"), registry.failures
    return lwbench_example_loader, registry


def _shuffled_folder(root: Path, write, scans: int = 2) -> Path:
    folder = root / "csv"
    folder.mkdir()
    rng = np.random.default_rng(1)
    for i in range(scans):
        points = room_scan(SENSOR, seed=i, index=i).points
        write(folder / f"{i:06d}.csv", points[rng.permutation(len(points))])
    return folder


def test_the_example_loader_imports_only_the_public_api():
    mods = graph_tool.example_modules()
    assert "lwbench_example_loader" in mods
    assert graph_tool.breaches(mods) == []
    imported = {target for target, _ in graph_tool._imports(mods["lwbench_example_loader"])}
    assert {t for t in imported if t.split(".")[0] == "lwbench"} <= set(graph_tool.PUBLIC)


def test_the_registry_finds_it_by_sniff_and_it_derives_and_flags_a_guessed_sensor(example, tmp_path):
    module, registry = example
    folder = _shuffled_folder(tmp_path, module.write_csv_scan)
    spec = resolve_dataset(registry, str(folder), {}, 0)  # what `lwbench run --dataset FOLDER` does
    assert spec.name == "csvscans" and registry.providers[("dataset", "csvscans")].startswith("LWBENCH_PLUGINS")
    ds = registry.dataset("csvscans")(path=str(folder))
    with pytest.warns(DataWarning, match="sensor model guessed"):
        frame = ds[0]
    assert ds.sensor_guessed and ds.derivation.guessed
    assert frame.sensor.n_beams == SENSOR.n_beams
    assert frame.sensor.azimuth_step_deg == pytest.approx(SENSOR.azimuth_step_deg, rel=0.01)


@pytest.mark.heavy
def test_a_study_on_it_stores_rows_flagged_sensor_guessed(example, tmp_path):
    module, registry = example
    folder = _shuffled_folder(tmp_path, module.write_csv_scan)
    store = tmp_path / "r.sqlite"
    request = RunRequest(datasets=(DatasetRequest(str(folder)),), codecs=("raw", "random"),
                         sequence_metrics=False, isolate=False, store=store)
    with pytest.warns(DataWarning, match="sensor model guessed"):
        outcome = Study.prepare(request, registry).run()
    assert all(s.evaluated == 4 for s in outcome.summaries)  # 2 scans x 2 codecs
    with ResultStore(store) as results:
        rows = list(results.rows())
        entries = build_leaderboard(results, info=registry.metric_info())
    assert len(rows) == 4 and all(r.sensor_guessed and r.dataset_id.startswith("csvscans:") for r in rows)
    assert {e.codec for e in entries} == {"raw", "random"}
    assert all("sensor_guessed" in e.flags for e in entries)


@pytest.mark.heavy
def test_the_example_loaders_own_tests_pass():
    """A third-party package runs lwbench.testing.check_dataset in its own test suite."""
    env = {**os.environ, "PYTHONPATH": str(EXAMPLE)}
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:dash", "-p", "no:cacheprovider", str(EXAMPLE / "tests")],
        env=env, capture_output=True, text=True, cwd=EXAMPLE,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert " passed" in res.stdout
