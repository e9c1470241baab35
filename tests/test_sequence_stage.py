"""The sequence stage streams: payloads kept (not decoded clouds), one task per (configuration,
metric) on the run's executor -- in process, worker processes, Ray -- with the same rows, and
progress from inside a task. The metric contract's memory check catches a metric that holds
the drive."""

from __future__ import annotations

import importlib.util
import re

import numpy as np
import pytest

from lwbench import MetricId, SequenceEvaluation, SequenceMetric
from lwbench.registry import get_registry
from lwbench.results.store import ResultStore
from lwbench.run import DatasetSpec, RunPlan, expand_codec_configs
from lwbench.run.record import DECODED, PAYLOAD
from lwbench.run.runner import Runner  # the internal under test
from lwbench.testing import ConformanceError, check_metric_streams

SIM = DatasetSpec("sim", {"frames": 5, "seed": 3})


def _plan(**kw) -> RunPlan:
    reg = get_registry()
    configs = [
        *expand_codec_configs(reg.codec("raw"), {}, 0),
        *expand_codec_configs(reg.codec("random"), {"ratio": ["0.2"]}, 0),
    ]
    return RunPlan(SIM, tuple(configs), **kw)


def _sequence_values(store: ResultStore) -> dict:
    return {
        (r.codec, r.part): (r.status, {k: v for k, v in r.metrics.items() if not k.endswith(("_ms", "_mb"))})
        for r in store.rows(kind="sequence")
    }


def _same(a: dict, b: dict) -> bool:
    """The same rows, to 1e-9 relative (Open3D's ICP reduces over threads: the last digit may move)."""
    if a.keys() != b.keys():
        return False
    for key, (status, values) in a.items():
        other_status, other = b[key]
        if status != other_status or values.keys() != other.keys():
            return False
        for k, v in values.items():
            w = other[k]
            if (v is None) != (w is None) or (v is not None and not np.isclose(v, w, rtol=1e-9, atol=1e-12)):
                return False
    return True


@pytest.fixture(scope="module")
def in_process(tmp_path_factory):
    path = tmp_path_factory.mktemp("seq") / "one.sqlite"
    events = []
    with ResultStore(path) as store:
        summary = Runner(store, _plan(), registry=get_registry()).run(events.append)
        yield store, summary, events


@pytest.mark.heavy
def test_every_configuration_and_metric_gets_a_row_from_payloads(in_process):
    store, summary, _ = in_process
    values = _sequence_values(store)
    assert summary.sequence_rows == 6 and len(values) == 6  # 2 configurations x 3 default metrics
    assert all(status == "ok" for status, _ in values.values()), values
    # raw is lossless: its localization and occupancy are the originals'
    assert values[("raw", "occupancy")][1]["occ_iou"] == 1.0
    assert values[("raw", "localization")][1]["icp_failures_original"] == 0.0


def test_the_run_keeps_payloads_and_only_the_gallery_frame_decoded(in_process):
    store, _, _ = in_process
    frames = [r for r in store.rows(kind="frame")]
    assert len(frames) == 10
    payload_bytes = 0
    for row in frames:
        payload = store.artifact(row.evaluation, PAYLOAD)
        assert payload is not None and payload.dtype == np.uint8
        assert len(payload) == row.metrics["bytes"]
        payload_bytes += len(payload)
        assert (store.artifact(row.evaluation, DECODED) is not None) == (row.frame == 0)
    # Beside the store: the payloads (compressed again) plus the gallery -- never every decoded cloud.
    on_disk = sum(p.stat().st_size for p in store.files.folder.rglob("*.lwbc"))
    gallery = sum(store.artifact(r.evaluation, DECODED).nbytes for r in frames if r.frame == 0)
    assert on_disk <= 1.2 * payload_bytes + gallery


def test_progress_comes_from_inside_a_task(in_process):
    _, _, events = in_process
    steps = [e.what for e in events if e.phase == "sequence-step"]
    assert steps, "no progress from inside the sequence stage"
    pattern = re.compile(r"^(raw|random\(.*\)) · (localization|odometry|occupancy) · .+ \d+/5$")
    assert all(pattern.match(w) for w in steps), steps[:5]
    assert any("tracking" in w for w in steps) and any("originals" in w for w in steps)


@pytest.mark.heavy
def test_worker_processes_give_the_same_rows(in_process, tmp_path):
    store, _, _ = in_process
    with ResultStore(tmp_path / "two.sqlite") as two:
        summary = Runner(two, _plan(), registry=get_registry(), workers=2).run()
        assert summary.failed == 0 and summary.sequence_rows == 6
        assert _same(_sequence_values(two), _sequence_values(store))


@pytest.mark.heavy
@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed here")
def test_ray_tasks_give_the_same_rows(in_process, tmp_path):
    import ray

    store, _, _ = in_process
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    try:
        with ResultStore(tmp_path / "ray.sqlite") as on_ray:
            summary = Runner(on_ray, _plan(), registry=get_registry(), executor="ray").run()
            assert summary.failed == 0 and summary.sequence_rows == 6
            assert _same(_sequence_values(on_ray), _sequence_values(store))
    finally:
        ray.shutdown()


@pytest.mark.heavy
def test_frames_stored_without_payloads_are_re_evaluated_for_the_sequence_metrics(in_process, tmp_path):
    store, _, _ = in_process
    with ResultStore(tmp_path / "later.sqlite") as later:
        first = Runner(later, _plan(sequence_metrics=False), registry=get_registry()).run()
        assert first.evaluated == 10 and first.sequence_rows == 0
        assert all(later.artifact(r.evaluation, PAYLOAD) is None for r in later.rows(kind="frame"))
        again = Runner(later, _plan(), registry=get_registry()).run()
        assert again.evaluated == 0 and again.skipped == 10 and again.sequence_rows == 6
        assert all(later.artifact(r.evaluation, PAYLOAD) is not None for r in later.rows(kind="frame"))
        assert _same(_sequence_values(later), _sequence_values(store))


class _Hoarder(SequenceMetric):
    """Keeps every decoded scan: what a sequence metric must not do."""

    name = "test-hoarder"
    ids = (MetricId("hoarded_points", "pts", "lower"),)

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        scans = list(seq.decoded)
        return {"hoarded_points": float(sum(len(s) for s in scans))}


class _Streamer(SequenceMetric):
    """The same figure, one step at a time."""

    name = "test-streamer"
    ids = (MetricId("streamed_points", "pts", "lower"),)

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        return {"streamed_points": float(sum(len(s.decoded) for s in seq.steps()))}


def test_the_contract_fails_a_metric_that_keeps_the_drive():
    with pytest.raises(ConformanceError, match="16 frames"):
        check_metric_streams(_Hoarder)
    check_metric_streams(_Streamer)


@pytest.mark.heavy
def test_every_installed_sequence_metric_streams():
    for name, cls in sorted(get_registry().sequence_metrics.items()):
        if name != "kiss" or importlib.util.find_spec("kiss_icp") is not None:
            check_metric_streams(cls)
