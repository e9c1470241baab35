"""The run: plan -> evaluate -> record -> sequence metrics, for one :class:`~.plan.RunPlan`.

:meth:`Runner.run` is the whole run path in order: open the dataset, work out which rows are
missing from the store (keys already there are skipped, which makes an interrupted run
resumable and a repeated command free), hand those frames to an executor, record each result
as it arrives, then run the sequence metrics. A codec or metric that raises becomes a ``failed``
row with its error and the run goes on; Ctrl-C leaves every finished row stored.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from lwbench.dataset import Dataset
from lwbench.errors import ParameterError
from lwbench.registry import Registry, get_registry
from lwbench.results.store import ResultRow, ResultStore

from .evaluate import Evaluator
from .execute import DEFAULT_TIMEOUT_S, PRELOAD, FrameTask, InProcessExecutor, ProcessExecutor, Worker
from .plan import CodecConfig, RunPlan
from .record import Provenance, RowFactory, record_frame, record_original
from .sequence import SequenceStage

__all__ = ["Progress", "RunSummary", "Runner"]


@dataclass
class RunSummary:
    evaluated: int = 0
    skipped: int = 0
    failed: int = 0
    sequence_rows: int = 0
    interrupted: bool = False
    failures: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Progress:
    """What :meth:`Runner.run` reports after each stored row -- and, inside the sequence stage,
    how far a running task is (``phase="sequence-step"``, ``row=None``, ``what``: configuration,
    metric, pass and frame, e.g. ``raw · localization · tracking 812/1600``)."""

    phase: str  # "frames" | "sequence" | "sequence-step"
    done: int
    total: int
    row: ResultRow | None = None
    what: str = ""


class Runner:
    def __init__(
        self,
        store: ResultStore,
        plan: RunPlan,
        *,
        registry: Registry | None = None,
        workers: int = 1,
        retry_failed: bool = False,
        force: bool = False,
        isolate: bool = False,
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
        memory_mb: int | None = None,
        executor: str = "local",
        address: str | None = None,
        dataset: Dataset | None = None,
        machine: str | None = None,
    ) -> None:
        """``isolate`` runs every evaluation in worker processes (``lwbench run`` does by
        default; more than one worker always does) with a per-call ``timeout_s`` and a memory
        ceiling of ``memory_mb`` per worker (default: 80 % of the machine's memory shared by
        the workers). ``executor="ray"`` sends the evaluations to a Ray cluster at ``address``
        (a local one when ``None``), as ``workers`` concurrent tasks at most."""
        self.store = store
        self.plan = plan
        self.configs: list[CodecConfig] = list(plan.configs)
        self.registry = registry or get_registry()
        self.workers = max(1, workers)
        self.retry_failed = retry_failed
        self.force = force
        self.isolate = isolate or self.workers > 1
        self.timeout_s = timeout_s
        self.memory_mb = memory_mb
        self.executor_name = executor
        self.address = address
        if executor not in ("local", "ray"):
            raise ParameterError(f"executor must be local or ray, got {executor!r}")
        if (self.isolate or executor == "ray") and self.registry.recipe() is None:
            raise ParameterError(
                "plugins registered as Python objects cannot be loaded in worker processes: run in process "
                "(isolate=False, workers=1) or register them as modules (LWBENCH_PLUGINS)"
            )
        self.dataset = dataset if dataset is not None else plan.dataset.build(self.registry)
        self.dataset_id = self.dataset.identity()
        self.frame_indices = plan.frame_indices(self.dataset)
        self.worker = Worker(self.registry, plan.metric_params, {plan.dataset.label: self.dataset})
        self.evaluator: Evaluator = self.worker.evaluator
        self.rows = RowFactory(
            self.registry, plan.dataset.label, self.dataset_id, plan.seed, self.evaluator.scoring,
            Provenance.current(machine), sensor_guessed=bool(self.dataset.sensor_guessed),
        )
        self.sequence: SequenceStage | None = None
        # Why asked-for sequence metrics will not run (said by the CLI, never silent): no poses.
        self.sequence_skipped = ""
        if plan.sequence_metrics and not self.dataset.has_poses:
            names = [m.name for m in self.registry.sequence_metric_instances(plan.metric_params, plan.metrics)]
            if names:
                self.sequence_skipped = (f"sequence metrics ({', '.join(names)}) skipped: "
                                         f"{self.dataset.why_no_poses()}")
        if plan.sequence_metrics and self.dataset.has_poses:
            metrics = self.registry.sequence_metric_instances(plan.metric_params, plan.metrics)
            if metrics:
                self.sequence = SequenceStage(store, self.dataset, plan.dataset, self.frame_indices, self.rows,
                                              metrics, plan.seed)

    # -- what the run asks for -------------------------------------------------------------
    def keys(self) -> set[str]:
        """Keys of every row this run asks for (frame rows and, with poses, sequence rows)."""
        out = {self.rows.frame_row(i, c).key for i in self.frame_indices for c in self.configs}
        if self.sequence is not None:
            out |= set(self.sequence.keys(self.configs))
        return out

    def _todo(self, key: str) -> bool:
        if self.force:
            return key not in self._done_now
        status = self.store.status(key)
        return status is None or (status == "failed" and self.retry_failed)

    def pending(self) -> list[FrameTask]:
        # Payloads are kept when the sequence stage will re-decode them; decoded clouds only for
        # the first frame (a report shows one decoded frame per configuration).
        first = self.frame_indices[0] if self.frame_indices else None
        tasks = []
        for i in self.frame_indices:
            configs = tuple(c for c in self.configs if self._todo(self.rows.frame_row(i, c).key))
            if configs:
                tasks.append(FrameTask(self.plan.dataset, i, configs, keep_decoded=i == first,
                                       keep_payload=self.sequence is not None))
        return tasks

    # -- the run ---------------------------------------------------------------------------
    def run(self, on_progress: Callable[[Progress], None] | None = None) -> RunSummary:
        """Evaluate what is not stored yet; ``on_progress`` is called after each stored row."""
        self._done_now: set[str] = set()
        summary = RunSummary()
        tasks = self.pending()
        total = sum(len(t.configs) for t in tasks)
        summary.skipped = len(self.frame_indices) * len(self.configs) - total
        executor = self.make_executor()

        def recorded(row: ResultRow, phase: str, done: int, n: int) -> None:
            self._done_now.add(row.key)
            if row.status == "failed":
                summary.failed += 1
                where = f"frame {row.frame}" if row.kind == "frame" else f"sequence metric {row.part}"
                summary.failures.append(f"{row.codec} {where}: {row.error}")
            if on_progress:
                on_progress(Progress(phase, done, n, row))

        try:
            if tasks and self.frame_indices:
                # The first frame's original is kept beside its decoded clouds (a report's gallery).
                first = self.frame_indices[0]
                record_original(self.store, self.dataset_id, first, self.dataset[first].points)
            for result in executor.map(tasks):
                row = record_frame(self.store, self.rows, result)
                summary.evaluated += 1
                recorded(row, "frames", summary.evaluated, total)
            if self.sequence is not None:
                # The sequence tasks run on the same executor as the frames (workers, Ray); a
                # frame whose payload is missing (rows of an older lwbench) is re-evaluated there.
                n = sum(self._todo(k) for k in self.sequence.keys(self.configs))
                if on_progress is not None:
                    def step(task, what: str, k: int, total: int) -> None:
                        on_progress(Progress("sequence-step", summary.sequence_rows, n, None,
                                             f"{task.label} · {what} {k}/{total}"))

                    executor.on_progress = step
                for row in self.sequence.run(self.configs, self._todo, executor):
                    summary.sequence_rows += 1
                    recorded(row, "sequence", summary.sequence_rows, n)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            executor.close()  # no worker outlives the run
        return summary

    def make_executor(self):
        """Where this run's evaluations go (see :mod:`.execute`, :mod:`.ray_executor`)."""
        if self.executor_name == "ray":
            from .ray_executor import RayExecutor

            return RayExecutor(self.registry, self.plan.metric_params, address=self.address,
                               max_in_flight=self.workers, timeout_s=self.timeout_s)
        if not self.isolate:
            return InProcessExecutor(self.worker)
        # Torch (a second or two to import) is preloaded only when a codec of the run uses it.
        torch = any(self.registry.codec(c.name).supports_gpu for c in self.configs)
        preload = tuple(m for m in PRELOAD if m != "torch" or torch)
        return ProcessExecutor(self.registry.recipe(), self.plan.metric_params, workers=self.workers,
                               timeout_s=self.timeout_s, memory_mb=self.memory_mb, preload=preload)
