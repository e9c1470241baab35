"""Evaluations as Ray tasks, for sweeps larger than one machine (``--executor ray``).

Each (frame, configuration) is one Ray task: its worker process rebuilds the driver's plugin
registry from its recipe once (Ray reuses worker processes, so start-up is paid once per
process, not per task), opens the dataset from its spec -- the data must be reachable at the
same path on every node, or come from a dataset that generates it, like ``sim`` -- and returns
the :class:`~.evaluate.FrameResult`. Results stream back to the driver as they complete, and the
driver alone writes the store, exactly as with the local executors.

Sequence tasks (one sequence metric over one configuration) are Ray tasks too: they read the
configuration's payloads from the files beside the results store, so on a multi-node cluster the
store's folder must be reachable at the same path on every node (a shared filesystem), as the data
is. A Ray task cannot report its progress while it runs, so a sequence task's time limit is the
per-call timeout once per 100 frames of its sequence.

Faults behave as in :class:`~.execute.ProcessExecutor`: a task still running after the per-call
timeout is cancelled (its worker killed) and recorded as failed; a task whose worker dies
(segfault, ``os._exit``, Ray's memory monitor) is recorded as failed, with Ray's reason.
Codecs that can use a GPU, asked for one (``device`` other than ``cpu``, and ``auto`` when the
cluster has GPUs), request ``num_gpus=1``; every task requests one CPU and runs one thread per
CPU it holds.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Iterator

from lwbench.errors import MissingDependencyError, ParameterError, WorkerError
from lwbench.registry import Registry, registry_from_recipe

from .execute import DEFAULT_TIMEOUT_S, Result, Task, Worker
from .plan import CodecConfig
from .tasks import SequenceTask, TaskQueue, stuck

__all__ = ["RayExecutor"]

_WORKERS: dict[str, Worker] = {}  # per Ray worker process, by (recipe, metric parameters)


def _evaluate(recipe, metric_params: dict, task: Task, threads: int) -> Result:
    """The Ray task: one frame through one configuration (or one sequence metric over one
    configuration), in a Ray worker process."""
    os.environ["LWBENCH_THREADS"] = str(threads)
    key = repr((recipe, sorted(metric_params.items())))
    worker = _WORKERS.get(key)
    if worker is None:
        worker = _WORKERS[key] = Worker(registry_from_recipe(recipe), metric_params)
    return worker.run(task)[0]


def _import_ray():
    try:
        import ray
    except ImportError:
        raise MissingDependencyError(
            "--executor ray needs Ray: install it with `pip install 'lwbench[ray]'`"
        ) from None
    return ray


class RayExecutor:
    """Evaluations on a Ray cluster (``address``; a local one when ``None`` and none is running)."""

    def __init__(self, registry: Registry, metric_params: dict | None = None, *, address: str | None = None,
                 max_in_flight: int = 1, timeout_s: float | None = DEFAULT_TIMEOUT_S, cpus_per_task: int = 1,
                 ray_init: dict | None = None) -> None:
        self.ray = ray = _import_ray()
        self.recipe = registry.recipe()
        if self.recipe is None:
            raise ParameterError("plugins registered as Python objects cannot be sent to Ray workers: register "
                                 "them as modules (LWBENCH_PLUGINS) or as installed packages")
        self.registry = registry
        self.metric_params = metric_params or {}
        self.timeout_s = timeout_s
        self.cpus_per_task = cpus_per_task
        self._owns = not ray.is_initialized()
        if self._owns:
            ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level="ERROR",
                     **(ray_init or {}))
        resources = ray.cluster_resources()
        self.gpus = float(resources.get("GPU", 0))
        slots = int(resources.get("CPU", 1)) // max(1, cpus_per_task)
        self.max_in_flight = max(1, max_in_flight if max_in_flight > 1 else slots)
        self._remote = ray.remote(max_retries=0)(_evaluate)
        self._pending: dict = {}
        self.on_progress = None  # a Ray task reports no progress before it returns

    def _wants_gpu(self, config: CodecConfig) -> bool:
        device = str(config.params.get("device", "cpu"))
        if not self.registry.codec(config.name).supports_gpu or device == "cpu":
            return False
        if device.startswith("cuda") and not self.gpus:
            raise ParameterError(f"{config.name}.device={device}: the Ray cluster has no GPU")
        return bool(self.gpus)

    def _submit(self, task: Task):
        (config,) = task.configs
        options = {"num_cpus": self.cpus_per_task}
        if self._wants_gpu(config):
            options["num_gpus"] = 1
        ref = self._remote.options(**options).remote(self.recipe, self.metric_params, task, self.cpus_per_task)
        self._pending[ref] = (task, time.monotonic())
        return ref

    def _failure(self, task: Task, why: str) -> Result:
        (config,) = task.configs
        return task.failure(config, WorkerError(why), {"isolation": why})

    def _limit_s(self, task: Task) -> float | None:
        """A task's time limit: the per-call timeout; a sequence task, which cannot report its
        progress from a Ray worker, gets it once per 100 frames of its sequence."""
        if self.timeout_s is None or not isinstance(task, SequenceTask):
            return self.timeout_s
        return self.timeout_s * max(1.0, len(task.frame_indices) / 100)

    def map(self, tasks: Iterable[Task] | TaskQueue) -> Iterator[Result]:
        ray = self.ray
        # One Ray task per evaluation: a timeout or a dead worker costs exactly one row.
        queue = tasks if isinstance(tasks, TaskQueue) else TaskQueue(one for t in tasks for one in t.split())
        while queue or self._pending:
            while queue and len(self._pending) < self.max_in_flight:
                task = queue.take()
                if task is None:
                    break
                self._submit(task)
            if not self._pending:
                raise stuck(queue)
            now = time.monotonic()
            wait_s = 1.0
            limits = [(t0, self._limit_s(t)) for t, t0 in self._pending.values()]
            if self.timeout_s is not None:
                wait_s = max(0.05, min(wait_s, *(t0 + lim - now for t0, lim in limits)))
            done, _ = ray.wait(list(self._pending), num_returns=1, timeout=wait_s)
            for ref in done:
                task, _ = self._pending.pop(ref)
                try:
                    yield ray.get(ref)
                except ray.exceptions.RayTaskError as exc:  # the task raised: lwbench's own bug
                    yield self._failure(task, f"the Ray task failed: {str(exc).splitlines()[0]}")
                except ray.exceptions.RayError as exc:  # the worker died, was killed or lost
                    yield self._failure(task, f"the Ray worker was lost during this evaluation ({type(exc).__name__})")
            if self.timeout_s is not None:
                now = time.monotonic()
                for ref, (task, t0) in list(self._pending.items()):
                    if now - t0 > self._limit_s(task):
                        ray.cancel(ref, force=True)
                        del self._pending[ref]
                        yield self._failure(task, f"timed out after {self._limit_s(task):g} s (the Ray task was "
                                                  "cancelled and its worker killed; --timeout)")

    def close(self) -> None:
        for ref in list(self._pending):
            self.ray.cancel(ref, force=True)
        self._pending.clear()
        if self._owns and self.ray.is_initialized():
            self.ray.shutdown()

    def __enter__(self) -> RayExecutor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
