"""Where evaluations run: in this process, or in a pool of worker processes.

An executor turns :class:`FrameTask` values into lists of :class:`~.evaluate.FrameResult` and
yields them as they complete; it never touches the store (the driver alone records), which is
what lets another executor (a cluster) slot in. Each worker process builds its registry, its
:class:`~.evaluate.Evaluator` and its datasets once, at start-up, not per task.

Threads: worker processes are started with ``spawn`` (forking after torch has started its thread
pool can hang torch calls in the child) and with the BLAS/OpenMP thread count set so that
workers x threads = cores, before any numerical library is imported in the worker.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context

from lwbench.dataset import Dataset
from lwbench.registry import Registry, get_registry

from .evaluate import Evaluator, FrameResult
from .plan import CodecConfig, DatasetSpec

__all__ = ["FrameTask", "Worker", "LocalExecutor"]

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


@dataclass(frozen=True)
class FrameTask:
    """One frame and the configurations to evaluate on it (they share its k-d trees)."""

    dataset: DatasetSpec
    frame: int
    configs: tuple[CodecConfig, ...]
    keep_decoded: bool = False


class Worker:
    """What one process needs to evaluate tasks: an evaluator and the datasets it has opened."""

    def __init__(self, registry: Registry, metric_params: dict[str, dict], datasets: dict | None = None) -> None:
        self.evaluator = Evaluator(registry, metric_params)
        self.registry = registry
        self.datasets: dict[str, Dataset] = dict(datasets or {})

    def run(self, task: FrameTask) -> list[FrameResult]:
        try:
            dataset = self.datasets.get(task.dataset.label)
            if dataset is None:
                dataset = self.datasets[task.dataset.label] = task.dataset.build(self.registry)
            frame = dataset[task.frame]
        except Exception as exc:  # noqa: BLE001 - a bad scan fails its rows, not the run
            err = RuntimeError(f"loading frame {task.frame}: {type(exc).__name__}: {exc}")
            return [FrameResult.failure(task.frame, c, err) for c in task.configs]
        return self.evaluator.evaluate(frame, task.configs, keep_decoded=task.keep_decoded)


_WORKER: Worker | None = None


def _init_worker(threads: int, metric_params: dict[str, dict]) -> None:
    global _WORKER
    for var in _THREAD_VARS:
        os.environ[var] = str(threads)
    _WORKER = Worker(get_registry(), metric_params)


def _run_task(task: FrameTask) -> list[FrameResult]:
    assert _WORKER is not None, "worker process was not initialised"
    return _WORKER.run(task)


class LocalExecutor:
    """``workers=1``: evaluate in this process, in order; more: a spawned process pool."""

    def __init__(self, worker: Worker, workers: int = 1, metric_params: dict[str, dict] | None = None) -> None:
        self.worker = worker
        self.workers = max(1, workers)
        self.metric_params = metric_params or {}

    def map(self, tasks: Iterable[FrameTask]) -> Iterator[list[FrameResult]]:
        tasks = list(tasks)
        if self.workers == 1 or len(tasks) <= 1:
            for task in tasks:
                yield self.worker.run(task)
            return
        threads = max(1, (os.cpu_count() or 1) // self.workers)
        with ProcessPoolExecutor(
            self.workers, mp_context=get_context("spawn"), initializer=_init_worker,
            initargs=(threads, self.metric_params),
        ) as pool:
            futures = [pool.submit(_run_task, t) for t in tasks]
            for fut in as_completed(futures):
                yield fut.result()
