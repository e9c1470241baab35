"""What one run asks for, however it was asked: a :class:`RunRequest`, and the :class:`Study` it runs.

Three front ends fill the same request -- the command line (``lwbench run``'s options), a TOML
run file (:mod:`.config`) and a quality gate (:mod:`lwbench.gates`) -- so they plan, check and
run a study the same way, and ``lwbench report --config`` calls :meth:`Study.run` instead of
replaying the ``run`` command. A request holds *words and values*, not built objects: turning
it into :class:`~.plan.RunPlan` s (one per dataset and seed) is :meth:`RunRequest.plans`, which
validates everything against the installed plugins.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from lwbench.dataset import Dataset
from lwbench.errors import MissingDependencyError, ParameterError
from lwbench.registry import Registry
from lwbench.results.store import ResultStore

from .execute import DEFAULT_TIMEOUT_S
from .plan import Grids, RunPlan, parse_assignments, parse_metric_params, parse_sweeps, plan_run, preflight
from .runner import Progress, Runner, RunSummary

__all__ = ["DEFAULT_STORE", "DatasetRequest", "PlanFinished", "PlanStarted", "RunRequest", "Study", "StudyEvent",
           "StudyOutcome"]

#: Where results go when neither the command line nor a run file says.
DEFAULT_STORE = Path("lwbench-results/results.sqlite")


@dataclass(frozen=True)
class DatasetRequest:
    """A dataset as a user names it: a registered name, a path, or ``None`` (the default one)."""

    source: str | None = None
    params: Mapping[str, Any] = field(default_factory=dict)
    frames: int | None = None  # this dataset's first N frames (None: the request's ``frames``)
    # this dataset's metric settings (a run file's per-dataset ``metric_params``: the simulator's
    # noise for the floor), merged key by key over the request's for this dataset's plans only
    metric_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def merged_metric_params(self, common: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
        """The request's metric settings with this dataset's over them (key by key)."""
        return {m: {**common.get(m, {}), **self.metric_params.get(m, {})}
                for m in dict.fromkeys([*common, *self.metric_params])}


@dataclass(frozen=True)
class RunRequest:
    """Datasets x codecs x parameter grids x seeds, and where and how to evaluate them."""

    datasets: tuple[DatasetRequest, ...] = (DatasetRequest(),)
    codecs: tuple[str, ...] = ()  # empty: the codecs that declare in_default_run
    # codec -> one grid (key -> values), or a list of grids whose union is run (a run file that
    # names a codec twice: ``lossless`` with one refine set, ``step`` swept with another)
    sweeps: Mapping[str, Grids] = field(default_factory=dict)
    frames: int | None = None  # the first N frames of every dataset
    seeds: tuple[int, ...] = (0,)
    metric_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    sequence_metrics: bool = True
    metrics: tuple[str, ...] = ()  # opt-in metrics named (--metric): see SequenceMetric.in_default_run
    # -- where and how (not part of any result's key) --
    store: Path | None = None  # None: DEFAULT_STORE
    workers: int = 1
    retry_failed: bool = False
    force: bool = False
    isolate: bool = True
    timeout_s: float | None = DEFAULT_TIMEOUT_S
    memory_mb: int | None = None
    executor: str = "local"
    address: str | None = None
    machine: str | None = None  # the rows' machine label (default: LWBENCH_MACHINE, else the host's description)
    suite: str | None = None  # NAME@VERSION+HASH of the suite this request is (lwbench suite run)

    def __post_init__(self) -> None:
        """Every refusal of a contradictory or impossible request lives here, so the command line,
        a run file and a gate refuse the same things with the same words -- options that contradict
        each other are refused, not resolved behind the user's back."""
        if self.executor not in ("local", "ray"):
            raise ParameterError(f"--executor must be local or ray, got {self.executor!r}")
        if not self.datasets or not self.seeds:
            raise ParameterError("a run needs at least one dataset and one seed")
        if self.workers < 1:
            raise ParameterError(f"--workers must be at least 1, got {self.workers}")
        if not self.isolate and self.workers > 1:
            raise ParameterError(f"--in-process evaluates in this process, one at a time: it cannot take --workers "
                                 f"{self.workers} (leave out one of them)")
        if self.address is not None and self.executor != "ray":
            raise ParameterError(f"--address {self.address} names a Ray cluster: it needs --executor ray")

    def check_installed(self) -> None:
        """What the request needs from this machine, before any work starts (not in
        ``__post_init__``: a request can be built and inspected where Ray is not installed)."""
        if self.executor == "ray" and importlib.util.find_spec("ray") is None:
            raise MissingDependencyError("--executor ray needs Ray, which is not installed: pip install 'lwbench[ray]'")

    @classmethod
    def from_words(
        cls,
        registry: Registry,
        *,
        dataset: str | None = None,
        dataset_params: Sequence[str] = (),
        codecs: Sequence[str] = (),
        params: Sequence[str] = (),
        metric_params: Sequence[str] = (),
        seed: int = 0,
        **options: Any,
    ) -> RunRequest:
        """A request from command-line words: ``--dataset-param KEY=VALUE``, ``--param
        CODEC.KEY=V1,V2``, ``--metric-param METRIC.KEY=VALUE`` (each checked as it is parsed)."""
        names = tuple(dict.fromkeys(codecs))
        owners = names or tuple(sorted(n for n, c in registry.codecs.items() if c.in_default_run))
        return cls(
            datasets=(DatasetRequest(dataset, parse_assignments(dataset_params, "--dataset-param")),),
            codecs=names,
            sweeps=parse_sweeps(params, owners, "--param"),
            seeds=(seed,),
            metric_params=parse_metric_params(metric_params, registry),
            **options,
        )

    def with_options(self, **options: Any) -> RunRequest:
        """The same study with other execution options (``--store`` on the command line wins
        over a run file's ``store``)."""
        return replace(self, **{k: v for k, v in options.items() if v is not None})

    @property
    def store_path(self) -> Path:
        return self.store if self.store is not None else DEFAULT_STORE

    def plans(self, registry: Registry) -> list[RunPlan]:
        """One validated :class:`RunPlan` per dataset and seed (every error a clear ``LwbenchError``)."""
        return [
            plan_run(
                registry,
                dataset=d.source,
                dataset_params=d.params,
                codecs=self.codecs,
                sweeps=self.sweeps,
                frames=d.frames if d.frames is not None else self.frames,
                seed=seed,
                metric_params=d.merged_metric_params(self.metric_params),
                sequence_metrics=self.sequence_metrics,
                metrics=self.metrics,
            )
            for d in self.datasets
            for seed in self.seeds
        ]


@dataclass
class StudyOutcome:
    """What a study did: one summary per plan, and the keys of every row it asked for."""

    summaries: list[RunSummary] = field(default_factory=list)
    keys: set[str] = field(default_factory=set)

    @property
    def interrupted(self) -> bool:
        return any(s.interrupted for s in self.summaries)


@dataclass(frozen=True)
class PlanStarted:
    """A plan (one dataset and seed) is about to run: what a front end announces."""

    index: int  # of the study's plans
    plan: RunPlan
    frames: int  # frames this plan evaluates
    configs: int  # codec configurations
    has_sequence_stage: bool
    sequence_skipped: str  # why asked-for sequence metrics will not run ("" when they will or were not asked)


@dataclass(frozen=True)
class PlanFinished:
    """A plan has run (or was interrupted: ``summary.interrupted``)."""

    index: int
    plan: RunPlan
    summary: RunSummary


#: What :meth:`Study.run` reports: a plan starts, a row is stored (or a sequence task moves), a plan ends.
StudyEvent = PlanStarted | Progress | PlanFinished


@dataclass
class Study:
    """A request planned and checked: built by :meth:`prepare` before anything is written.

    :meth:`run` is the one way anything in lwbench evaluates codecs -- ``lwbench run``, run files,
    ``lwbench report --config`` and the quality gates all call it -- so a refusal, a preflight
    check or a resume rule holds for every front end at once.
    """

    request: RunRequest
    registry: Registry
    plans: list[RunPlan]
    datasets: list[Dataset]

    @classmethod
    def prepare(cls, request: RunRequest, registry: Registry) -> Study:
        """Plan the request and check everything that can be checked before the store is opened
        (a bad dataset, scan, sensor file or device is an error now, with nothing written)."""
        request.check_installed()
        plans = request.plans(registry)
        local = request.executor != "ray"  # a cluster's devices are the cluster's to check
        return cls(request, registry, plans, [preflight(registry, plan, local_devices=local) for plan in plans])

    def run(self, results: ResultStore | None = None,
            on_event: Callable[[StudyEvent], None] | None = None) -> StudyOutcome:
        """Every plan into ``results`` (default: the request's store, opened here), in order;
        ``on_event`` hears each :data:`StudyEvent`. Stops after a plan that was interrupted (its
        finished rows are stored; the same study resumes)."""
        if results is None:
            with ResultStore(self.request.store_path) as opened:
                return self.run(opened, on_event)
        r = self.request
        outcome = StudyOutcome()
        # What the rows are scored with travels with them: a board read where a metric plugin is
        # missing ranks and flags as here (lwbench.results.leaderboard.board_info).
        results.declare_metrics(self.registry.metric_declarations())
        for index, (plan, dataset) in enumerate(zip(self.plans, self.datasets, strict=True)):
            runner = Runner(results, plan, registry=self.registry, workers=r.workers, retry_failed=r.retry_failed,
                            force=r.force, isolate=r.isolate, timeout_s=r.timeout_s, memory_mb=r.memory_mb,
                            executor=r.executor, address=r.address, dataset=dataset, machine=r.machine)
            if on_event is not None:
                on_event(PlanStarted(index, plan, len(runner.frame_indices), len(runner.configs),
                                     runner.sequence is not None, runner.sequence_skipped))
            summary = runner.run(on_event)
            outcome.summaries.append(summary)
            keys = runner.keys()
            outcome.keys |= keys
            if r.suite is not None:  # cached rows too: a suite's rows say which suite asked for them
                results.tag_suite(r.suite, keys)
            if on_event is not None:
                on_event(PlanFinished(index, plan, summary))
            if summary.interrupted:
                break
        return outcome
