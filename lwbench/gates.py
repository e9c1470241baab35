"""Quality gates: run one codec configuration on a dataset and hold its metrics to thresholds.

This is what the pytest plugin (:mod:`lwbench.pytest_plugin`, fixture ``lwbench_gate``) calls,
and what a script can call directly::

    result = run_gate("vsgp", dataset="sim", dataset_params={"scene": "tunnel"}, frames=10)
    result.require(max_range_rmsd=0.095, min_coverage=0.99, min_ratio=90)

A threshold is ``max_<id>`` or ``min_<id>`` for any installed metric id, on the mean over the
frames; ``<id>_median``, ``<id>_p95`` and ``<id>_std`` gate those statistics instead. Failed rows
always fail the gate. The run goes through the normal store, so a gate in CI reuses what an
earlier step already measured (same configuration, same frames: same keys) and computes only
what is missing.
"""

from __future__ import annotations

import functools
import math
import types
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lwbench.errors import LwbenchError, ParameterError
from lwbench.registry import Registry, get_registry, new_registry
from lwbench.results.leaderboard import STATS, LeaderboardEntry, build_leaderboard

if TYPE_CHECKING:
    from lwbench.run import RunRequest

__all__ = ["GateFailure", "GateResult", "gate_plan", "gate_request", "parse_threshold", "run_gate"]


class GateFailure(AssertionError):
    """A gate's thresholds were not met (an ``AssertionError``, so pytest reports it as a failure)."""


def parse_threshold(name: str, registry: Registry) -> tuple[str, str, str]:
    """``max_range_rmsd_p95`` -> ("max", "range_rmsd", "p95"); unknown ids raise ``ParameterError``."""
    bound, sep, rest = name.partition("_")
    if bound not in ("min", "max") or not sep:
        raise ParameterError(f"gate threshold {name!r}: write min_<metric id> or max_<metric id>")
    ids = registry.metric_info()
    stat = "mean"
    for s in STATS[1:]:
        if rest.endswith(f"_{s}") and rest[: -len(s) - 1] in ids:
            rest, stat = rest[: -len(s) - 1], s
    if rest not in ids:
        raise ParameterError(f"gate threshold {name!r}: unknown metric id {rest!r}; valid: {', '.join(ids)}")
    return bound, rest, stat


@dataclass
class GateResult:
    """One configuration's results on the gated frames."""

    entry: LeaderboardEntry
    dataset: str
    frame_values: dict[str, dict[int, float]]  # metric -> frame -> value
    registry: Registry = field(repr=False)
    failures: list[str] = field(default_factory=list)  # errors of failed rows

    @property
    def label(self) -> str:
        return self.entry.full_label

    @property
    def frames(self) -> int:
        return self.entry.frames

    def value(self, metric: str, stat: str = "mean") -> float | None:
        return self.entry.value(metric, stat)

    def _worst(self, metric: str, bound: str) -> str:
        values = self.frame_values.get(metric)
        if not values:
            return ""
        frame = max(values, key=values.get) if bound == "max" else min(values, key=values.get)
        return f"; worst frame {frame}: {_fmt(values[frame], self._unit(metric))}"

    def _unit(self, metric: str) -> str:
        info = self.registry.metric_info().get(metric)
        return getattr(info, "unit", "") if info is not None else ""

    def require(self, **thresholds: float) -> GateResult:
        """Check every ``min_<id>=`` / ``max_<id>=`` threshold; raise :class:`GateFailure`
        listing each one missed (and every failed row) with measured vs required values."""
        lines = [f"{len(self.failures)} failed row(s): {self.failures[0]}"] if self.failures else []
        ok = []
        for name, limit in thresholds.items():
            bound, metric, stat = parse_threshold(name, self.registry)
            measured = self.value(metric, stat)
            unit = self._unit(metric)
            what = metric if stat == "mean" else f"{metric} ({stat})"
            need = f"{'<=' if bound == 'max' else '>='} {_fmt(limit, unit)}"
            if measured is None or (isinstance(measured, float) and math.isnan(measured)):
                lines.append(f"{what}: no value (the metric is undefined on these frames), required {need}")
                continue
            passed = measured <= limit if bound == "max" else measured >= limit
            text = f"{what} = {_fmt(measured, unit)} ({stat} over {self.frames} frames), required {need}"
            if passed:
                ok.append(text)
            else:
                lines.append(text + (self._worst(metric, bound) if stat == "mean" else ""))
        if lines:
            head = f"lwbench gate failed: {self.label} on {self.dataset}, {self.frames} frame(s)"
            body = "\n".join(f"  {line}" for line in lines)
            passed_text = "".join(f"\n  ok: {t}" for t in ok)
            raise GateFailure(f"{head}\n{body}{passed_text}")
        return self


def _fmt(value: float, unit: str) -> str:
    text = f"{value:.4g}"
    return f"{text} {unit}" if unit and unit not in ("share", "x") else text


@functools.cache
def _registry_with(codec_cls: type) -> Registry:
    """A registry that also knows an unregistered codec class (a team's codec under test)."""
    from lwbench.hookspecs import hookimpl

    reg = new_registry()
    plugin = types.SimpleNamespace(lwbench_codecs=hookimpl(lambda: [codec_cls]))
    if not reg.register(plugin, f"gate:{codec_cls.__module__}.{codec_cls.__name__}", provider=codec_cls.__module__):
        raise LwbenchError(f"cannot register {codec_cls!r}: {reg.failures[-1].error}")
    return reg


def gate_request(
    codec: str | type,
    *,
    params: Mapping[str, Any] | None = None,
    dataset: str | Path | None = None,
    dataset_params: Mapping[str, Any] | None = None,
    frames: int | None = None,
    seed: int = 0,
    metric_params: Mapping[str, Mapping[str, Any]] | None = None,
    sequence_metrics: bool = False,
    metrics: Sequence[str] = (),
    registry: Registry | None = None,
) -> tuple[Registry, RunRequest]:
    """The registry and the :class:`~lwbench.run.RunRequest` of a gate: a request like the
    command line's, of one codec configuration, evaluated in this process (a gate's codec may
    be a class defined in the test file, which no worker process could import)."""
    from lwbench.run import DatasetRequest, RunRequest

    if isinstance(codec, type):
        registry = _registry_with(codec)
        codec = codec.name
    registry = registry or get_registry()
    request = RunRequest(
        datasets=(DatasetRequest(str(dataset) if dataset is not None else None, dict(dataset_params or {})),),
        codecs=(codec,),
        sweeps={codec: {k: [v] for k, v in (params or {}).items()}},
        frames=frames,
        seeds=(seed,),
        metric_params=metric_params or {},
        sequence_metrics=sequence_metrics,
        metrics=tuple(metrics),
        isolate=False,
    )
    return registry, request


def gate_plan(codec: str | type, **options: Any):
    """The registry and the one-configuration :class:`~lwbench.run.RunPlan` of a gate (``options``
    are :func:`gate_request`'s)."""
    registry, request = gate_request(codec, **options)
    (plan,) = request.plans(registry)
    if len(plan.configs) != 1:
        raise ParameterError("a gate runs exactly one codec configuration")
    return registry, plan


def run_gate(codec: str | type, *, store: str | Path | None = None, **options: Any) -> GateResult:
    """Evaluate one codec configuration (``codec``: a registered name or a Codec class) on the
    first ``frames`` frames of ``dataset`` and return its results (then ``.require(...)``).

    ``options`` are :func:`gate_request`'s. The gate runs through :meth:`lwbench.run.Study.run`,
    the path every front end takes (the same preflight checks and refusals as ``lwbench run``).
    ``store``: an existing results store is reused (cache hits); ``None`` keeps the results in
    memory only. Sequence metrics (localization,
    occupancy) run only with ``sequence_metrics=True``; opt-in ones (kiss) only when also named
    in ``metrics``.
    """
    from lwbench.results.store import ResultStore
    from lwbench.run import Study

    registry, request = gate_request(codec, **options)
    study = Study.prepare(request, registry)
    (plan,) = study.plans
    if len(plan.configs) != 1:
        raise ParameterError("a gate runs exactly one codec configuration")
    with ResultStore(store if store is not None else ":memory:") as results:
        keys = study.run(results).keys
        (entry,) = build_leaderboard(results, keys=keys, info=registry.metric_info(), min_coverage=0.0)
        frame_values: dict[str, dict[int, float]] = {}
        failures = []
        for row in results.rows():
            if row.key not in keys:
                continue
            if row.status != "ok":
                failures.append(f"frame {row.frame}: {row.error}" if row.kind == "frame" else str(row.error))
            elif row.kind == "frame":
                for metric, value in row.metrics.items():
                    if value is not None and math.isfinite(value):
                        frame_values.setdefault(metric, {})[row.frame] = value
    return GateResult(entry, plan.dataset.label, frame_values, registry, failures)
