"""Runtime metrics: the runner measures, this metric reports (so the ids are registered and
listed like any other). Times are ``time.perf_counter_ns`` around each call, steady state: the
first call of each codec configuration in a process is a separate warm-up pass, stored apart."""

from __future__ import annotations

from lwbench import LOWER, Evaluation, FrameMetric, MetricId


class RuntimeMetric(FrameMetric):
    name = "runtime"
    order = 40
    version = "2"  # 1: peak_mb without the heap's free pages handed back first (raw read 0 MiB)
    ids = (
        MetricId("encode_ms", "ms", LOWER, default=True, role="runtime"),
        MetricId("decode_ms", "ms", LOWER, default=True, role="runtime"),
        MetricId("select_ms", "ms", LOWER, role="runtime"),  # part of encode_ms: behind --columns
        MetricId("peak_mb", "MiB", LOWER),
    )
    description = (
        "wall time per call (ms; a selection codec's encode_ms is its whole encode, select_ms -- its "
        "select() -- plus the shared serializer); peak_mb = resident memory encode+decode added, the C heap's "
        "free pages returned first (MiB: the working set, not what earlier frames happened to free)"
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        t = ev.timings_ms
        return {
            "encode_ms": t.get("encode_ms"),
            "decode_ms": t.get("decode_ms"),
            "select_ms": t.get("select_ms"),
            "peak_mb": ev.peak_mb,
        }
