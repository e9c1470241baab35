"""Runtime metrics: the runner measures, this metric reports (so the ids are registered and
listed like any other). Times are ``time.perf_counter_ns`` around each call, steady state: the
first call of each codec configuration in a process is a separate warm-up pass, stored apart."""

from __future__ import annotations

from lwbench import LOWER, Evaluation, FrameMetric, MetricId


class RuntimeMetric(FrameMetric):
    name = "runtime"
    order = 40
    ids = (
        MetricId("encode_ms", "ms", LOWER, default=True, role="runtime"),
        MetricId("decode_ms", "ms", LOWER, default=True, role="runtime"),
        MetricId("select_ms", "ms", LOWER, default=True, role="runtime"),
        MetricId("peak_mb", "MiB", LOWER),
    )
    description = (
        "wall time per call (ms; select_ms for selection codecs, whose encode_ms is then the "
        "shared serializer); peak_mb = peak resident memory added during encode+decode (MiB)"
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        t = ev.timings_ms
        return {
            "encode_ms": t.get("encode_ms"),
            "decode_ms": t.get("decode_ms"),
            "select_ms": t.get("select_ms"),
            "peak_mb": ev.peak_mb,
        }
