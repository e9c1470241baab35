"""Stage 4 -- sequence metrics: localization, odometry, occupancy over a configuration's frames.

Each (codec configuration, sequence metric) is one :class:`SequenceTask`, run by the same
executors as the frames (in process, ``--workers`` processes, Ray tasks), so the stage that is
two thirds of a long run's time is parallel too. A task holds no decoded cloud: it names the
configuration's *payloads* (files beside the store, by digest) and its worker decodes each one
when the metric's pass reaches it (:class:`~lwbench.metric.SequenceEvaluation`). Memory follows
the metric's own state (a voxel map: the area covered), not the number of frames.

What depends only on the original scans (the original occupancy map, the tracking of the
originals) is computed once per dataset: the first configuration's task of each metric runs
first, and the cache entries it made (:meth:`SequenceEvaluation.cached`) travel with that
metric's other tasks -- an explicit cache owned by this stage, not a hidden module-level one.

A frame row with no stored payload (rows recorded by an older lwbench, or without the sequence
stage) is re-evaluated through the same executor, with its payload kept, and recorded first.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lwbench.artifacts import CloudFiles
from lwbench.dataset import Dataset
from lwbench.errors import LwbenchError, StoreError
from lwbench.metric import SequenceMetric
from lwbench.store import ResultRow, ResultStore

from .plan import CodecConfig, DatasetSpec
from .record import PAYLOAD, RowFactory, record_frame

__all__ = ["PayloadRefs", "SequenceResult", "SequenceStage", "SequenceTask"]

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


@dataclass
class SequenceStage:
    store: ResultStore
    dataset: Dataset
    dataset_spec: DatasetSpec
    frame_indices: list[int]
    rows: RowFactory
    metrics: list[SequenceMetric]
    seed: int = 0
    # Per metric name: what its first task computed on the originals (SequenceEvaluation.cached).
    shared: dict[str, dict[str, Any]] = field(default_factory=dict)

    def keys(self, configs: list[CodecConfig]) -> list[str]:
        return [self.rows.sequence_row(c, m).key for c in configs for m in self.metrics]

    # -- payloads ---------------------------------------------------------------------------
    def _refs(self, config: CodecConfig) -> tuple[PayloadRefs | None, int, list[int]]:
        """(the configuration's payloads or None, frames that failed, frames with no payload)."""
        failed, missing, digests, inline = 0, [], [], []
        for i in self.frame_indices:
            row = self.rows.frame_row(i, config)
            if self.store.status(row.key) == "failed":
                failed += 1
                continue
            if self.store.files is None:
                array = self.store.artifact(row.evaluation, PAYLOAD)
                if array is None:
                    missing.append(i)
                else:
                    inline.append(array.tobytes())
                continue
            digest = self.store.artifact_digest(row.evaluation, PAYLOAD)
            if digest is None:
                missing.append(i)
            else:
                digests.append(digest)
        if failed or missing:
            return None, failed, missing
        if self.store.files is None:
            return PayloadRefs(None, inline=tuple(inline)), 0, []
        return PayloadRefs(str(self.store.files.folder), tuple(digests)), 0, []

    def _payloads(self, configs: list[CodecConfig], executor) -> dict[str, PayloadRefs | Exception]:
        """Each configuration's payloads; frames without one are re-evaluated (payload kept) and
        recorded first. A configuration with a failed frame gets the error its metrics fail with."""
        from .execute import FrameTask

        lacking = {c.key: self._refs(c)[2] for c in configs}
        tasks = [FrameTask(self.dataset_spec, i, (c,), keep_payload=True) for c in configs for i in lacking[c.key]]
        if tasks:
            for result in executor.map(tasks):
                record_frame(self.store, self.rows, result)
        out: dict[str, PayloadRefs | Exception] = {}
        for c in configs:
            refs, failed, missing = self._refs(c)
            if failed or missing:
                why = f"{failed} of {len(self.frame_indices)} frames failed to encode/decode" if failed else (
                    f"{len(missing)} frame payload(s) could not be stored")
                out[c.key] = LwbenchError(why)
            else:
                out[c.key] = refs
        return out

    # -- the stage --------------------------------------------------------------------------
    def run(self, configs: list[CodecConfig], todo: Callable[[str], bool], executor) -> Iterator[ResultRow]:
        """Compute and store every (configuration, metric) row ``todo`` says is missing."""
        by_name = {m.name: m for m in self.metrics}
        wanted = [(c, [m for m in self.metrics if todo(self.rows.sequence_row(c, m).key)]) for c in configs]
        wanted = [(c, ms) for c, ms in wanted if ms]
        if not wanted:
            return
        payloads = self._payloads([c for c, _ in wanted], executor)
        first, rest = [], []
        seen: set[str] = set()
        for config, metrics in wanted:
            refs = payloads[config.key]
            for metric in metrics:
                if isinstance(refs, Exception):
                    yield self._store(config, metric, "failed", error=f"{type(refs).__name__}: {refs}")
                    continue
                task = (config, metric, refs)
                if metric.name in seen or metric.name in self.shared:
                    rest.append(task)
                else:
                    seen.add(metric.name)
                    first.append(task)
        # The first task of each metric computes what the originals give (once per run); the
        # others start from it.
        for batch in (first, rest):
            tasks = [self._task(c, m, refs) for c, m, refs in batch]
            for result in executor.map(tasks):
                metric = by_name[result.metric]
                if result.status == "ok" and result.shared:
                    self.shared.setdefault(metric.name, {}).update(result.shared)
                yield self._store(result.config, metric, result.status, result.metrics, result.extra, result.error)

    def _task(self, config: CodecConfig, metric: SequenceMetric, refs: PayloadRefs) -> SequenceTask:
        return SequenceTask(self.dataset_spec, config, metric.name, tuple(self.frame_indices), self.seed, refs,
                            dict(self.shared.get(metric.name, {})))

    def _store(self, config: CodecConfig, metric: SequenceMetric, status: str, values: dict | None = None,
               extra: dict | None = None, error: str | None = None) -> ResultRow:
        row = self.rows.sequence_row(config, metric, status, values or {}, extra or {}, error)
        self.store.put(row)
        return row
