"""Opt-in sequence metrics (``SequenceMetric.in_default_run = False``): left out of a default run,
computed when named (``lwbench run --metric NAME``, a run file's ``metrics``)."""

from __future__ import annotations

import types

import numpy as np
import pytest
from typer.testing import CliRunner

from lwbench import (
    Dataset,
    Frame,
    MetricId,
    ParameterError,
    PluginError,
    RepresentationCodec,
    SequenceEvaluation,
    SequenceMetric,
    get_sensor,
    hookimpl,
)
from lwbench.cli import app
from lwbench.registry import new_registry
from lwbench.results.store import ResultStore
from lwbench.run import DatasetSpec, plan_run
from lwbench.run.config import read_run_file
from lwbench.run.runner import Runner  # the internal under test


class PassCodec(RepresentationCodec):
    name = "pass"

    def encode(self, frame: Frame) -> bytes:
        return self.make_payload(frame, {"n": len(frame)}, frame.points.tobytes())

    def decode(self, data: bytes) -> np.ndarray:
        return np.frombuffer(self.read_payload(data).body, np.float32).reshape(-1, 3)


class PosedDataset(Dataset):
    name = "posed"

    def __len__(self) -> int:
        return 3

    @property
    def has_poses(self) -> bool:
        return True

    def frame(self, index: int) -> Frame:
        pts = np.random.default_rng(index).uniform(-8, 8, (500, 3)).astype(np.float32)
        pose = np.eye(4)
        pose[0, 3] = index
        return Frame(pts, get_sensor("vlp16"), index=index, pose=pose)


class DecodedPoints(SequenceMetric):
    """Counts the decoded points of the sequence (a default sequence metric)."""

    name = "decoded_points"
    ids = (MetricId("seq_points", "points"),)

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        return {"seq_points": float(sum(len(d) for d in seq.decoded))}


class SlowFrames(SequenceMetric):
    """Counts the decoded frames; declared not in the default run, as a slow metric would be."""

    name = "slow_frames"
    ids = (MetricId("slow_frames_n", "frames"),)
    in_default_run = False

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        return {"slow_frames_n": float(len(seq.decoded))}


@pytest.fixture
def registry():
    reg = new_registry(load=False)
    plugin = types.SimpleNamespace(
        lwbench_codecs=hookimpl(lambda: [PassCodec]),
        lwbench_datasets=hookimpl(lambda: [PosedDataset]),
        lwbench_metrics=hookimpl(lambda: [DecodedPoints, SlowFrames]),
    )
    assert reg.register(plugin, "opt-in-plugin")
    return reg


def _sequence_values(reg, tmp_path, **plan) -> dict[str, float]:
    run_plan = plan_run(reg, dataset="posed", codecs=["pass"], **plan)
    with ResultStore(tmp_path / "r.sqlite") as store:
        Runner(store, run_plan, registry=reg).run()
        return {k: v for r in store.rows() if r.kind == "sequence" for k, v in r.metrics.items()}


def test_default_sequence_metrics_leave_the_opt_in_one_out(registry, tmp_path):
    assert [m.name for m in registry.sequence_metric_instances()] == ["decoded_points"]
    assert _sequence_values(registry, tmp_path) == {"seq_points": 1500.0}


def test_naming_an_opt_in_metric_runs_it_beside_the_defaults(registry, tmp_path):
    assert [m.name for m in registry.sequence_metric_instances(named=["slow_frames"])] == [
        "decoded_points",
        "slow_frames",
    ]
    assert _sequence_values(registry, tmp_path, metrics=["slow_frames"]) == {"seq_points": 1500.0, "slow_frames_n": 3.0}


def test_a_run_of_only_opt_in_metrics_has_no_sequence_stage(tmp_path):
    reg = new_registry(load=False)
    plugin = types.SimpleNamespace(
        lwbench_codecs=hookimpl(lambda: [PassCodec]),
        lwbench_datasets=hookimpl(lambda: [PosedDataset]),
        lwbench_metrics=hookimpl(lambda: [SlowFrames]),
    )
    assert reg.register(plugin, "only-opt-in")
    with ResultStore(tmp_path / "r.sqlite") as store:
        runner = Runner(store, plan_run(reg, dataset="posed", codecs=["pass"]), registry=reg)
        assert runner.sequence is None
        assert runner.run().sequence_rows == 0


def test_unknown_or_contradictory_names_are_refused(registry):
    with pytest.raises(PluginError, match="unknown metric"):
        plan_run(registry, dataset="posed", codecs=["pass"], metrics=["nope"])
    with pytest.raises(ParameterError, match="no-sequence-metrics"):
        plan_run(registry, dataset="posed", codecs=["pass"], metrics=["slow_frames"], sequence_metrics=False)


def test_run_file_names_opt_in_metrics(tmp_path):
    path = tmp_path / "run.toml"
    path.write_text('metrics = ["kiss"]\n[[dataset]]\nname = "sim"\n[[codec]]\nname = "raw"\n')
    assert read_run_file(path).metrics == ("kiss",)


def test_kiss_is_opt_in_and_listed_so(monkeypatch):
    from lwbench.registry import get_registry

    reg = get_registry()
    assert "kiss" in reg.sequence_metrics and not reg.sequence_metrics["kiss"].in_default_run
    assert "kiss" not in [m.name for m in reg.sequence_metric_instances()]
    assert "kiss" in [m.name for m in reg.sequence_metric_instances(named=["kiss"])]
    monkeypatch.setenv("COLUMNS", "250")
    out = CliRunner().invoke(app, ["list"], catch_exceptions=False).output
    assert "opt-in: --metric kiss" in out


def test_dataset_spec_is_unchanged_by_named_metrics(registry):
    plan = plan_run(registry, dataset="posed", codecs=["pass"], metrics=["slow_frames", "slow_frames"])
    assert plan.metrics == ("slow_frames",) and plan.dataset == DatasetSpec("posed", {})


def test_a_gate_names_opt_in_metrics_like_the_command_line():
    from lwbench.gates import gate_plan

    _, plan = gate_plan("raw", dataset="sim", frames=1, sequence_metrics=True, metrics=["kiss"])
    assert plan.metrics == ("kiss",)
    _, plain = gate_plan("raw", dataset="sim", frames=1, sequence_metrics=True)
    assert plain.metrics == ()
