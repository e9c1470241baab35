"""Metric cost per frame on a real 124k-point KITTI scan, and the runner's own overhead.

Run: ``pytest tests/benchmarks/test_bench_metrics.py -m benchmark --benchmark-enable``.
Figures are reported relative to references measured in the same run (the machines are noisy):
each metric against the ``raw`` codec's encode+decode, and the runner's bookkeeping against the
codec time of ``raw`` and ``random``.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from lwbench_metrics import GeometryMetric, RangeMetric, SizeMetric
from lwbench_plugins.files import KittiDataset

from lwbench import CodecKind, Evaluation
from lwbench.registry import get_registry
from lwbench.results.store import ResultStore
from lwbench.run import DatasetSpec, RunPlan, expand_codec_configs
from lwbench.run.runner import Runner  # the internal under test

pytestmark = pytest.mark.benchmark


@pytest.fixture(scope="module")
def frame(real_data):
    return KittiDataset(path=str(real_data / "kitti00_frames0-1"), sensor="hdl64e")[0]


@pytest.fixture(scope="module")
def decoded(frame):
    rng = np.random.default_rng(0)
    return (frame.points + rng.normal(0, 0.01, frame.points.shape)).astype(np.float32)


@pytest.mark.parametrize("metric_cls", [SizeMetric, RangeMetric, GeometryMetric])
def test_metric_time_per_frame(benchmark, metric_cls, frame, decoded):
    """Cold cache each round: the per-frame cost when one codec is evaluated."""

    def run():
        ev = Evaluation(frame, b"x" * 1000, decoded, CodecKind.REPRESENTATION, {})
        return metric_cls().compute(ev)

    benchmark(run)


@pytest.mark.parametrize("codec", ["raw", "random"])
def test_runner_overhead_share(benchmark, codec, real_data, tmp_path):
    """Runner time per row minus codec and metric time, as a share of the codec's time."""
    reg = get_registry()
    spec = DatasetSpec("kitti", {"path": str(real_data / "kitti00_frames0-1"), "sensor": "hdl64e"})
    configs = expand_codec_configs(reg.codec(codec), {}, 0)
    counter = iter(range(10_000))

    def one_run():
        with ResultStore(tmp_path / f"{next(counter)}.sqlite") as store:
            t0 = time.perf_counter()
            Runner(store, RunPlan(spec, tuple(configs), sequence_metrics=False), registry=reg).run()
            wall = time.perf_counter() - t0
            rows = list(store.rows())
        return wall, rows

    wall, rows = benchmark.pedantic(one_run, rounds=3, iterations=1)
    assert all(r.status == "ok" for r in rows)
    ms = {k: sum((r.metrics.get(k) or 0) for r in rows) for k in ("encode_ms", "decode_ms", "select_ms")}
    codec_ms = sum(ms.values())
    warm_ms = sum(v for r in rows for k, v in r.extra.items() if k.startswith("warmup_"))
    metric_ms = sum(r.extra["metrics_ms"] for r in rows)
    overhead_ms = wall * 1e3 - codec_ms - warm_ms - metric_ms
    benchmark.extra_info.update(
        codec_ms=codec_ms,
        warmup_ms=warm_ms,
        metrics_ms=metric_ms,
        overhead_ms=overhead_ms,
        overhead_share_of_codec=overhead_ms / codec_ms,
    )
    print(
        f"\n{codec}: codec {codec_ms:.0f} ms, warm-up {warm_ms:.0f} ms, metrics {metric_ms:.0f} ms, "
        f"runner overhead {overhead_ms:.0f} ms = {overhead_ms / codec_ms:.2f}x codec time"
    )
