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
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from multiprocessing.connection import wait

from lwbench.dataset import Dataset
from lwbench.errors import LwbenchError, MissingDependencyError, WorkerError
from lwbench.registry import Registry, registry_from_recipe
from lwbench.sandbox import Sandbox, SandboxError, cap_memory, enter_child, how_it_died

from .evaluate import Evaluator, FrameResult
from .plan import CodecConfig, DatasetSpec

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
        return list(self.run_each(task))

    def run_each(self, task: FrameTask, on_start: Callable[[CodecConfig], None] | None = None
                 ) -> Iterator[FrameResult]:
        """Each configuration's result as it is done; ``on_start`` is told before each begins."""
        try:
            dataset = self.datasets.get(task.dataset.label)
            if dataset is None:
                dataset = self.datasets[task.dataset.label] = task.dataset.build(self.registry)
            frame = dataset[task.frame]
        except Exception as exc:  # noqa: BLE001 - a bad scan fails its rows, not the run
            err = RuntimeError(f"loading frame {task.frame}: {type(exc).__name__}: {exc}")
            yield from (FrameResult.failure(task.frame, c, err) for c in task.configs)
            return
        each = self.evaluator.evaluate_each(frame, task.configs, keep_decoded=task.keep_decoded)
        for config in task.configs:
            if on_start is not None:
                on_start(config)
            yield next(each)


class InProcessExecutor:
    """Evaluate in this process, in order (``--in-process``: no isolation, for debugging and
    for registries built from objects, which a worker process cannot rebuild)."""

    def __init__(self, worker: Worker) -> None:
        self.worker = worker

    def map(self, tasks: Iterable[FrameTask]) -> Iterator[FrameResult]:
        for task in tasks:
            yield from self.worker.run_each(task)

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
            for result in worker.run_each(task, on_start=lambda c: conn.send(("start", c.key))):
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
    def _assign(self, slot: _Slot, task: FrameTask) -> None:
        slot.task, slot.remaining, slot.current, slot.deadline = task, list(task.configs), None, None
        slot.box.send(task)

    def _lost(self, slot: _Slot, why: str, queue: deque) -> list[FrameResult]:
        """The slot's worker is gone: its current evaluation fails with ``why``, the rest of its
        task goes back to the front of the queue, and the worker is replaced."""
        task = slot.task
        blamed = [slot.current] if slot.current is not None else list(slot.remaining)
        failed = [FrameResult.failure(task.frame, c, WorkerError(why), {"isolation": why}) for c in blamed]
        rest = tuple(c for c in slot.remaining if c not in blamed)
        if rest:
            queue.appendleft(FrameTask(task.dataset, task.frame, rest, task.keep_decoded))
        slot.task = None
        self._replace(slot)
        return failed

    def map(self, tasks: Iterable[FrameTask]) -> Iterator[FrameResult]:
        queue = deque(tasks)
        if not queue:
            return
        self._ensure(min(self.workers, len(queue)))
        by_key = {c.key: c for t in queue for c in t.configs}
        while queue or any(s.task is not None for s in self._slots):
            for slot in self._slots:
                if slot.task is None and queue:
                    self._assign(slot, queue.popleft())
            busy = [s for s in self._slots if s.task is not None]
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
