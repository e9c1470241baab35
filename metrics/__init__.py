"""lwbench's shared metrics, registered through the ``core_metrics`` entry point.

One module per family; every codec is scored by the same code. Definitions: docs/design.md and
docs/metrics.md.
"""

from __future__ import annotations

from lwbench_metrics.geometry import GeometryMetric
from lwbench_metrics.ranges import RangeMetric
from lwbench_metrics.runtime import RuntimeMetric
from lwbench_metrics.size import SizeMetric

from lwbench import FrameMetric, hookimpl

__all__ = ["GeometryMetric", "RangeMetric", "RuntimeMetric", "SizeMetric"]


@hookimpl
def lwbench_metrics() -> list[type[FrameMetric]]:
    return [SizeMetric, RangeMetric, GeometryMetric, RuntimeMetric]
