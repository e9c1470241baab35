"""What a board knows of its metric ids: the declarations the store kept, then the installed
metrics'; and each runtime as a multiple of the machine's reference workload."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from lwbench.metric import LOWER, MetricId
from lwbench.results.store import ResultStore

__all__ = ["board_info", "normalized_runtime_ids"]


def normalized_runtime_ids(info: Mapping[str, MetricId]) -> dict[str, str]:
    """Each runtime id in ms and its id as a multiple of the reference workload: ``encode_ms``
    -> ``encode_x`` (found by role and unit, not by name)."""
    return {i: (i[:-3] if i.endswith("_ms") else i) + "_x" for i, m in info.items()
            if getattr(m, "role", "") == "runtime" and getattr(m, "unit", "") == "ms"}


def board_info(store: ResultStore | None, installed: Iterable[Mapping[str, Any]]) -> dict[str, MetricId]:
    """The metric declarations a board of ``store`` reads: those the store kept for the metrics
    its rows were scored with (so a board ranks and flags the same on a machine without the
    plugin), then the installed metrics' (``Registry.metric_declarations()``) for the rest; and
    the runtimes as multiples of the reference workload (:func:`normalized_runtime_ids`)."""
    from lwbench.metric import info_from_declarations

    stored = store.metric_declarations() if store is not None else []
    names = {d["name"] for d in stored}
    info = info_from_declarations([*stored, *(d for d in installed if d["name"] not in names)])
    for x_id in normalized_runtime_ids(info).values():
        info[x_id] = MetricId(x_id, "x ref", LOWER)
    return info
