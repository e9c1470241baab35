"""Where evaluations run: in this process, or in isolated worker processes.

An executor turns :class:`FrameTask` values into :class:`~.evaluate.FrameResult` values and
yields them as they complete; it never touches the store (the driver alone records), which is
what lets another executor (a cluster, :mod:`.ray_executor`) slot in.

:class:`ProcessExecutor` is what ``lwbench run`` uses: every evaluation runs in a worker
process, so that one plugin cannot take the run down with it --

- **per-call timeout**: a worker reports when it starts each (frame, configuration); one that
  takes longer than ``timeout_s`` is killed, its evaluation recorded as failed, the rest of its
  task handed to a fresh worker;
- **dead workers are replaced**: a worker killed by a segfault or ``os._exit`` costs the
  evaluation it was running one failure row (saying how it died), not the run;
- **memory ceiling**: each worker's data segment is capped (``RLIMIT_DATA``), so a memory bomb
  fails with ``MemoryError`` (a failure row; the worker is then recycled) instead of taking
  the machine; a native library's failed allocation aborts the worker, which is replaced;
- **no worker outlives the run**: workers die with their parent (``PR_SET_PDEATHSIG`` and a
  watchdog thread), also when the driver is SIGKILLed;
- **start-up once per worker, threads per worker**: a worker builds its registry, evaluator and
  datasets once, and is started with ``cores // workers`` threads for every numerical library
  (:mod:`lwbench.parallel`), so two workers on two cores do not fight over four threads.

Workers are started with ``spawn`` (forking after torch has started its thread pool can hang
torch calls in the child), and rebuild the driver's registry from its recipe
(:meth:`lwbench.registry.Registry.recipe`).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from pathlib import Path

from lwbench.dataset import Dataset
from lwbench.errors import LwbenchError, MissingDependencyError, WorkerError
from lwbench.measure import Stopwatch
from lwbench.metric import SequenceEvaluation
from lwbench.registry import Registry, registry_from_recipe
from lwbench.results.artifacts import CloudFiles
from lwbench.sandbox import Sandbox, SandboxError, cap_memory, enter_child, how_it_died

from .evaluate import Evaluator, FrameResult, decoded_cloud
from .heap import HeapReturner
from .plan import CodecConfig, DatasetSpec
from .tasks import (
    FrameTask,
    Result,
    SequenceResult,
    SequenceTask,
    Task,
    TaskQueue,
    Throttle,
    as_queue,
    failed_result,
    stuck,
)

__all__ = [
    "DEFAULT_TIMEOUT_S",
    "FrameTask",
    "InProcessExecutor",
    "ProcessExecutor",
    "Worker",
    "default_memory_mb",
]

#: Per-call timeout (s) of ``lwbench run``: over ten times the slowest built-in codec at its defaults
#: on the largest real sample (see docs/hostile.md), so only a hang reaches it.
DEFAULT_TIMEOUT_S = 3600.0
_START_TIMEOUT_S = 300.0  # a worker's imports on a loaded machine
#: Modules a worker imports while it starts (the metrics' Open3D and SciPy, torch for the learned
#: codecs), so that a per-call timeout measures the evaluation, not the imports.
PRELOAD = ("open3d", "scipy.spatial", "torch")
_MEMORY_MARKERS = ("MemoryError", "can't allocate memory", "Cannot allocate memory")




class Worker:
    """What one process needs to evaluate tasks: an evaluator and the datasets it has opened."""

    def __init__(self, registry: Registry, metric_params: dict[str, dict], datasets: dict | None = None) -> None:
        self.evaluator = Evaluator(registry, metric_params)
        self.registry = registry
        self.metric_params = metric_params
        self.datasets: dict[str, Dataset] = dict(datasets or {})

    def dataset(self, spec: DatasetSpec) -> Dataset:
        dataset = self.datasets.get(spec.label)
        if dataset is None:
            dataset = self.datasets[spec.label] = spec.build(self.registry)
        return dataset

    def run(self, task: Task) -> list[Result]:
        return list(self.run_each(task))

    def run_each(self, task: Task, on_start: Callable[[CodecConfig], None] | None = None,
                 on_progress: Callable[[SequenceTask, str, int, int], None] | None = None) -> Iterator[Result]:
        """Each configuration's result as it is done; ``on_start`` is told before each begins,
        ``on_progress`` how far a sequence task's pass is."""
        if isinstance(task, SequenceTask):
            if on_start is not None:
                on_start(task.config)
            yield run_sequence_task(self, task, on_progress)
            return
        try:
            dataset = self.dataset(task.dataset)
            frame = dataset[task.frame]
        except Exception as exc:  # noqa: BLE001 - a bad scan fails its rows, not the run
            err = RuntimeError(f"loading frame {task.frame}: {type(exc).__name__}: {exc}")
            yield from (FrameResult.failure(task.frame, c, err) for c in task.configs)
            return
        each = self.evaluator.evaluate_each(frame, task.configs, keep_decoded=task.keep_decoded,
                                            keep_payload=task.keep_payload)
        for config in task.configs:
            if on_start is not None:
                on_start(config)
            yield next(each)


def run_sequence_task(worker: Worker, task: SequenceTask,
                      on_progress: Callable[[SequenceTask, str, int, int], None] | None = None) -> SequenceResult:
    """One sequence metric over one configuration: the payloads decoded as the metric's passes
    reach them, by one receiver (a decoder handed the dataset's sensor, as in the frame stage)."""
    try:
        dataset = worker.dataset(task.dataset)
        cls = worker.registry.sequence_metrics[task.metric]
        metric = cls(**worker.metric_params.get(task.metric, {}))
        codec_cls = worker.registry.codec(task.config.name)
        sensor = getattr(dataset, "sensor", None) or dataset[task.frame_indices[0]].sensor
        decoder = codec_cls(**task.config.params).use_sensors([sensor])

        def decode(position: int):
            return decoded_cloud(task.config.name, decoder.decode(task.payloads.get(position)))

        cache = dict(task.shared)
        before = set(cache)
        report = None if on_progress is None else Throttle(lambda what, k, n: on_progress(task, what, k, n))
        give_back = HeapReturner()

        def on_step(what: str, k: int, n: int) -> None:
            give_back()  # between scans: what the last one freed goes back (lwbench.run.heap)
            if report is not None:
                report(what, k, n)

        files = None if task.payloads.folder is None else CloudFiles(Path(task.payloads.folder))
        seq = SequenceEvaluation(dataset, list(task.frame_indices), decode, task.config.name, task.config.params,
                                 task.seed, _cache=cache, on_step=on_step, files=files)
        watch = Stopwatch()
        with watch.time("metric_ms"):
            values = metric.compute(seq)
        return SequenceResult(task.config, task.metric, "ok", values, dict(watch.ms),
                              shared={k: v for k, v in cache.items() if k not in before})
    except MissingDependencyError:
        raise  # the machine, not the codec: stop the run with the install hint
    except Exception as exc:  # noqa: BLE001 - the failure is the result
        return failed_result(task, exc)


class InProcessExecutor:
    """Evaluate in this process, in order (``--in-process``: no isolation, for debugging and
    for registries built from objects, which a worker process cannot rebuild)."""

    def __init__(self, worker: Worker) -> None:
        self.worker = worker
        self.on_progress: Callable[[SequenceTask, str, int, int], None] | None = None

    def map(self, tasks: Iterable[Task] | TaskQueue) -> Iterator[Result]:
        queue = as_queue(tasks)
        while queue:
            task = queue.take()
            if task is None:
                raise stuck(queue)
            yield from self.worker.run_each(task, on_progress=self.on_progress)

    def close(self) -> None:
        pass

    def __enter__(self) -> InProcessExecutor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def default_memory_mb(workers: int) -> int:
    """A worker's memory ceiling by default: 80 % of the machine's memory, shared by the workers."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20
    except (ValueError, OSError, AttributeError):
        return 0
    return int(0.8 * total / max(1, workers))


# -- the worker process ---------------------------------------------------------------------------
def _worker_main(conn, parent: int, recipe, metric_params: dict, memory_mb: int, preload: tuple[str, ...]) -> None:
    enter_child(parent)
    # Ctrl-C reaches every process of the terminal's group: the driver alone answers it (it stores
    # what finished and stops the workers), so a worker neither dies with a traceback nor prints
    # a stray "Process lwbench-worker:" line.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    worker = Worker(registry_from_recipe(recipe), metric_params)
    for module in preload:  # start-up once per worker: not inside the first evaluation's timeout
        with contextlib.suppress(Exception):
            if module == "open3d":
                from lwbench.deps import import_open3d  # with the libusb it needs

                import_open3d()
            else:
                importlib.import_module(module)
    cap_memory(memory_mb)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        recycle = False
        try:
            for result in worker.run_each(task, on_start=lambda c: conn.send(("start", c.key)),
                                          on_progress=lambda t, what, k, n: conn.send(("progress", what, k, n))):
                conn.send(("result", result))
                recycle = recycle or any(m in (result.error or "") for m in _MEMORY_MARKERS)
        except MissingDependencyError as exc:  # the machine, not a codec: the driver stops the run
            conn.send(("fatal", str(exc)))
            return
        conn.send(("done", recycle))
        if recycle:  # what a leak left behind would fail every later evaluation: start afresh
            return


# -- the driver's side ----------------------------------------------------------------------------
@dataclass
class _Slot:
    box: Sandbox
    task: FrameTask | None = None
    remaining: list[CodecConfig] = field(default_factory=list)
    current: CodecConfig | None = None
    deadline: float | None = None


class ProcessExecutor:
    """Evaluations in ``workers`` isolated processes (see the module docstring)."""

    def __init__(self, recipe, metric_params: dict | None = None, *, workers: int = 1,
                 timeout_s: float | None = DEFAULT_TIMEOUT_S, memory_mb: int | None = None,
                 threads: int | None = None, preload: tuple[str, ...] = PRELOAD) -> None:
        if recipe is None:
            raise LwbenchError(
                "plugins registered as Python objects cannot be loaded in worker processes: run in process "
                "(--in-process / isolate=False, one worker) or register them as modules (LWBENCH_PLUGINS)"
            )
        self.recipe = recipe
        self.metric_params = metric_params or {}
        self.workers = max(1, workers)
        self.timeout_s = timeout_s
        self.memory_mb = default_memory_mb(self.workers) if memory_mb is None else memory_mb
        self.threads = threads or max(1, (os.cpu_count() or 1) // self.workers)
        self.preload = tuple(preload)
        self._slots: list[_Slot] = []
        self.started = 0  # worker processes started (replacements included)
        # Told how far a worker's sequence task is (task, what, done, total); each report also
        # restarts that task's timeout: a long pass that advances is not a hang.
        self.on_progress: Callable[[SequenceTask, str, int, int], None] | None = None

    # -- workers ----------------------------------------------------------------------------
    def _spawn(self, n: int = 1) -> list[_Slot]:
        """``n`` fresh workers, started together (their imports overlap), each ready."""
        boxes = [Sandbox(_worker_main, (self.recipe, self.metric_params, self.memory_mb, self.preload),
                         name="lwbench-worker", threads=self.threads) for _ in range(n)]
        for box in boxes:
            box.spawn()
        self.started += n
        try:
            deadline = time.monotonic() + _START_TIMEOUT_S
            for box in boxes:
                box.wait_ready(max(0.0, deadline - time.monotonic()), "a worker process")
        except SandboxError as exc:
            for box in boxes:
                box.stop(kill=True)
            raise LwbenchError(f"{exc}: a plugin that crashes on import? `lwbench list` shows the plugins") from None
        return [_Slot(box) for box in boxes]

    def _ensure(self, n: int) -> None:
        self._slots += self._spawn(n - len(self._slots))

    def _replace(self, slot: _Slot) -> None:
        slot.box.stop(kill=True)
        self._slots[self._slots.index(slot)] = self._spawn()[0]

    def close(self) -> None:
        """Stop every worker (killed if busy): none outlives the run."""
        for slot in self._slots:
            slot.box.stop(kill=slot.task is not None)
        self._slots = []

    def __enter__(self) -> ProcessExecutor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- tasks ------------------------------------------------------------------------------
    def _assign(self, slot: _Slot, task: Task) -> None:
        slot.task, slot.remaining, slot.current, slot.deadline = task, list(task.configs), None, None
        slot.box.send(task)

    def _lost(self, slot: _Slot, why: str, queue: TaskQueue) -> list[Result]:
        """The slot's worker is gone: its current evaluation fails with ``why``, the rest of its
        task goes back to the front of the queue, and the worker is replaced."""
        task = slot.task
        blamed = [slot.current] if slot.current is not None else list(slot.remaining)
        failed = [task.failure(c, WorkerError(why), {"isolation": why}) for c in blamed]
        rest = task.rest(tuple(c for c in slot.remaining if c not in blamed))
        if rest is not None:
            queue.appendleft(rest)
        slot.task = None
        self._replace(slot)
        return failed

    def map(self, tasks: Iterable[Task] | TaskQueue) -> Iterator[Result]:
        queue = as_queue(tasks)
        if not queue:
            return
        self._ensure(min(self.workers, len(queue)))
        by_key = {c.key: c for t in queue.items for c in t.configs}
        while queue or any(s.task is not None for s in self._slots):
            for slot in self._slots:
                if slot.task is None and queue:
                    task = queue.take()
                    if task is not None:
                        self._assign(slot, task)
            busy = [s for s in self._slots if s.task is not None]
            if not busy:
                raise stuck(queue)
            now = time.monotonic()
            deadlines = [s.deadline - now for s in busy if s.deadline is not None]
            wait([s.box.conn for s in busy] + [s.box.sentinel for s in busy],
                 timeout=min([1.0, *deadlines]) if deadlines else 1.0)
            for slot in busy:
                died = False
                try:
                    while slot.task is not None and slot.box.poll(0):
                        kind, *payload = slot.box.recv()
                        if kind == "start":
                            slot.current = by_key[payload[0]]
                            slot.deadline = None if self.timeout_s is None else time.monotonic() + self.timeout_s
                        elif kind == "progress":  # a sequence task's pass: alive, and how far
                            if self.timeout_s is not None:
                                slot.deadline = time.monotonic() + self.timeout_s
                            if self.on_progress is not None:
                                self.on_progress(slot.task, *payload)
                        elif kind == "result":
                            result = payload[0]
                            slot.remaining = [c for c in slot.remaining if c.key != result.config.key]
                            slot.current, slot.deadline = None, None
                            yield result
                        elif kind == "fatal":
                            raise MissingDependencyError(payload[0])
                        elif kind == "done":
                            slot.task = None
                            if payload[0]:  # a memory failure: the worker recycles itself
                                self._replace(slot)
                except (EOFError, OSError):
                    died = True
                if slot.task is None:
                    continue
                if died or not slot.box.alive:
                    why = f"the worker process {how_it_died(slot.box.kill())} during this evaluation"
                    yield from self._lost(slot, why, queue)
                elif slot.deadline is not None and time.monotonic() > slot.deadline:
                    why = f"timed out after {self.timeout_s:g} s (the worker was killed and replaced; --timeout)"
                    yield from self._lost(slot, why, queue)
