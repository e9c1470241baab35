"""``Study.run`` is the one run path: every front end (CLI, run file, gate, ``report --config``)
goes through it, and every refusal lives in the request, so the API refuses what the CLI does."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

import pytest

from lwbench.errors import MissingDependencyError, ParameterError
from lwbench.registry import get_registry
from lwbench.run import DatasetRequest, PlanFinished, PlanStarted, Progress, RunRequest, Study

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("options, words", [
    ({"isolate": False, "workers": 2}, "--in-process"),
    ({"address": "ray://head:10001"}, "--executor ray"),
    ({"executor": "dask"}, "local or ray"),
    ({"workers": 0}, "at least 1"),
    ({"seeds": ()}, "one seed"),
])
def test_contradictory_requests_are_refused_by_the_request_itself(options, words):
    with pytest.raises(ParameterError, match=words):
        RunRequest(codecs=("raw",), **options)


def test_a_run_file_request_is_refused_the_same_way(tmp_path):
    from lwbench.run.config import read_run_file

    path = tmp_path / "run.toml"
    path.write_text('workers = 3\n[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n')
    with pytest.raises(ParameterError, match="--in-process"):
        read_run_file(path).with_options(isolate=False)


def test_ray_missing_is_refused_before_anything_is_planned(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    with pytest.raises(MissingDependencyError, match="lwbench\\[ray\\]"):
        Study.prepare(RunRequest(codecs=("raw",), executor="ray"), get_registry())


def test_a_gate_refuses_a_bad_dataset_in_preflight_as_lwbench_run_does(tmp_path):
    from lwbench.errors import LwbenchError
    from lwbench.gates import run_gate

    with pytest.raises(LwbenchError, match="does not exist|no such|not found"):
        run_gate("raw", dataset=tmp_path / "missing-folder", frames=1)


def test_study_run_reports_each_plan_and_row_in_order(tmp_path):
    request = RunRequest(datasets=(DatasetRequest("sim", {"scene": "tunnel"}, frames=1),), codecs=("raw", "random"),
                         seeds=(0, 1), sequence_metrics=False, isolate=False, store=tmp_path / "s.sqlite")
    events = []
    outcome = Study.prepare(request, get_registry()).run(on_event=events.append)
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["PlanStarted", "Progress", "Progress", "PlanFinished"] * 2
    started = [e for e in events if isinstance(e, PlanStarted)]
    assert [e.plan.seed for e in started] == [0, 1] and all(e.frames == 1 and e.configs == 2 for e in started)
    assert all(e.summary.evaluated == 2 for e in events if isinstance(e, PlanFinished))
    assert all(e.phase == "frames" for e in events if isinstance(e, Progress))
    assert len(outcome.keys) == 4
    # The same study again: every row cached, nothing evaluated.
    again = Study.prepare(request, get_registry()).run()
    assert [(s.evaluated, s.skipped) for s in again.summaries] == [(0, 2), (0, 2)]


def test_nothing_outside_the_study_constructs_a_runner():
    """The grep the architecture issue names, as a test: ``Runner`` is the study's internal (its
    own unit tests, test_runner.py and test_sequence_stage.py, construct it to test it)."""
    callers = []
    for path in [*ROOT.joinpath("lwbench").rglob("*.py"), *ROOT.joinpath("plugins").rglob("*.py"),
                 *ROOT.joinpath("metrics").rglob("*.py"), *ROOT.joinpath("tools").rglob("*.py"),
                 *ROOT.joinpath("examples").rglob("*.py")]:
        if path.name in ("runner.py", "request.py") and path.parent.name == "run":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "Runner":
                callers.append(str(path.relative_to(ROOT)))
    assert callers == []
