"""What executors run: a frame's evaluations (:class:`FrameTask`) or one sequence metric over one
configuration (:class:`SequenceTask`), and what comes back. Both kinds travel to worker
processes and Ray tasks, so they are small and picklable: a sequence task names its payloads
(:class:`PayloadRefs`), it does not carry them."""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lwbench.errors import LwbenchError, StoreError
from lwbench.results.artifacts import CloudFiles

from .evaluate import FrameResult
from .plan import CodecConfig, DatasetSpec

__all__ = ["FrameTask", "PayloadRefs", "Result", "SequenceResult", "SequenceTask", "Task", "TaskQueue", "Throttle"]


@dataclass(frozen=True)
class FrameTask:
    """One frame and the configurations to evaluate on it (they share its k-d trees);
    ``keep_decoded``: return the decoded clouds (a report's gallery), ``keep_payload``: the
    payloads (the sequence stage re-decodes them)."""

    dataset: DatasetSpec
    frame: int
    configs: tuple[CodecConfig, ...]
    keep_decoded: bool = False
    keep_payload: bool = False

    @property
    def label(self) -> str:
        return f"frame {self.frame}"

    def failure(self, config: CodecConfig, exc: BaseException, extra: dict | None = None) -> FrameResult:
        return FrameResult.failure(self.frame, config, exc, extra)

    def split(self) -> list[FrameTask]:
        """One task per configuration (a Ray task each)."""
        return [FrameTask(self.dataset, self.frame, (c,), self.keep_decoded, self.keep_payload) for c in self.configs]

    def rest(self, configs: tuple[CodecConfig, ...]) -> FrameTask | None:
        """The same task for the ``configs`` not done yet (a lost worker's remainder)."""
        return FrameTask(self.dataset, self.frame, configs, self.keep_decoded, self.keep_payload) if configs else None


#: How often a worker reports a sequence task's progress (and so proves it is alive), seconds.
PROGRESS_EVERY_S = 1.0


@dataclass(frozen=True)
class PayloadRefs:
    """A configuration's payloads, frame by frame: files beside the store named by digest (what a
    worker process reads, no store needed), or the bytes themselves (an in-memory store)."""

    folder: str | None
    digests: tuple[str, ...] = ()
    inline: tuple[bytes, ...] = ()

    def __len__(self) -> int:
        return len(self.digests) if self.folder is not None else len(self.inline)

    def get(self, position: int) -> bytes:
        if self.folder is None:
            return self.inline[position]
        array = CloudFiles(Path(self.folder)).get(self.digests[position])
        if array is None:
            raise StoreError(f"the payload file {self.digests[position]} is gone from {self.folder}")
        return array.tobytes()


@dataclass
class SequenceResult:
    """The outcome of one (configuration, sequence metric): values, or the error that stopped it;
    ``shared``: the cache entries it computed on the originals (for the metric's other tasks)."""

    config: CodecConfig
    metric: str
    status: str
    metrics: dict[str, float | None] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    shared: dict[str, Any] = field(default_factory=dict)
    frame: int = -1


@dataclass(frozen=True)
class SequenceTask:
    """One sequence metric over one configuration's frames (see the module docstring)."""

    dataset: DatasetSpec
    config: CodecConfig
    metric: str
    frame_indices: tuple[int, ...]
    seed: int
    payloads: PayloadRefs
    shared: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)

    frame = -1  # the executors' bookkeeping: not a frame
    keep_decoded = False

    @property
    def configs(self) -> tuple[CodecConfig, ...]:
        return (self.config,)

    @property
    def label(self) -> str:
        return f"{self.config.label} · {self.metric}"

    def failure(self, config: CodecConfig, exc: BaseException, extra: dict | None = None) -> SequenceResult:
        return SequenceResult(config, self.metric, "failed", extra=extra or {}, error=f"{type(exc).__name__}: {exc}")

    def split(self) -> list[SequenceTask]:
        return [self]

    def rest(self, configs: tuple[CodecConfig, ...]) -> SequenceTask | None:
        return None  # one configuration: nothing is left when it is lost


def failed_result(task: SequenceTask, exc: BaseException) -> SequenceResult:
    out = task.failure(task.config, exc)
    out.extra["traceback"] = traceback.format_exc(limit=6)
    return out


class Throttle:
    """Calls ``report(what, done, total)`` at most every ``every_s`` seconds (and at a pass's end)."""

    def __init__(self, report: Callable[[str, int, int], None], every_s: float = PROGRESS_EVERY_S) -> None:
        self.report, self.every_s, self.last = report, every_s, float("-inf")

    def __call__(self, what: str, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last >= self.every_s or done >= total:
            self.last = now
            self.report(what, done, total)


#: Reports a sequence task's progress: (task, what the pass is, frames done, frames in the pass).
TaskReporter = Callable[[SequenceTask, str, int, int], None]


Task = FrameTask | SequenceTask
Result = FrameResult | SequenceResult


class TaskQueue:
    """Tasks in order, each handed out once ``ready(task)`` says it may run (a sequence metric's
    later configurations wait for its first one, which computes what the originals give), after
    ``prepare(task)`` (which hands it what that first task computed). An executor takes the first
    ready task whenever a worker is free, so nothing waits on a whole batch."""

    def __init__(self, tasks, ready: Callable[[Task], bool] | None = None,
                 prepare: Callable[[Task], Task] | None = None) -> None:
        self.items: list[Task] = list(tasks)
        self.ready = ready or (lambda task: True)
        self.prepare = prepare or (lambda task: task)

    def __len__(self) -> int:
        return len(self.items)

    def __bool__(self) -> bool:
        return bool(self.items)

    def take(self) -> Task | None:
        """The first ready task (removed, prepared), or None when every one left waits."""
        for i, task in enumerate(self.items):
            if self.ready(task):
                del self.items[i]
                return self.prepare(task)
        return None

    def appendleft(self, task: Task) -> None:
        """Put a task back in front (the rest of a lost worker's task): it is ready."""
        self.items.insert(0, task)


def as_queue(tasks) -> TaskQueue:
    return tasks if isinstance(tasks, TaskQueue) else TaskQueue(tasks)


def stuck(queue: TaskQueue) -> LwbenchError:
    return LwbenchError(f"{len(queue)} task(s) wait on results that will not come (a bug in lwbench)")
