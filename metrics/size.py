"""Rate metrics: what the payload costs on the link (docs/design.md, "Metrics")."""

from __future__ import annotations

from lwbench import HIGHER, LOWER, Evaluation, FrameMetric, MetricId


class SizeMetric(FrameMetric):
    """``bytes`` is always ``len(payload)``: the real serialized size, header and checksum
    included, so a codec cannot look smaller by leaving metadata out of its count."""

    name = "size"
    order = 10
    ids = (
        MetricId("bytes", "B", LOWER, default=True, role="rate", quantity="bytes_per_frame"),
        MetricId("ratio", "x", HIGHER, default=True, headline=True),
        MetricId("bits_per_point", "bit", LOWER, role="rate", quantity="rate_bits_per_point"),
        MetricId("link_kbps", "kB/s", LOWER),
        MetricId("points_in", "pts", quantity="input_points"),
        MetricId("points_out", "pts"),
    )
    description = (
        "payload bytes; ratio = 12*|P| / bytes; bits per original point; link rate in kB/s "
        "(1 kB = 1000 B) at the sensor's frame rate; point counts in and out"
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        n_bytes = len(ev.payload)
        n_in = len(ev.frame)
        return {
            "bytes": float(n_bytes),
            "ratio": ev.frame.raw_bytes / n_bytes if n_bytes else None,
            "bits_per_point": 8.0 * n_bytes / n_in if n_in else None,
            "link_kbps": n_bytes * ev.frame.sensor.rate_hz / 1000.0,
            "points_in": float(n_in),
            "points_out": float(len(ev.decoded)),
        }
