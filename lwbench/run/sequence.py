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

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

from lwbench.dataset import Dataset
from lwbench.errors import LwbenchError
from lwbench.metric import SequenceMetric
from lwbench.results.store import ResultRow, ResultStore

from .plan import CodecConfig, DatasetSpec
from .record import PAYLOAD, RowFactory, record_frame
from .tasks import FrameTask, PayloadRefs, SequenceTask, TaskQueue

__all__ = ["SequenceStage"]


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
        tasks: list[SequenceTask] = []
        firsts: set[int] = set()
        for config, metrics in wanted:
            refs = payloads[config.key]
            for metric in metrics:
                if isinstance(refs, Exception):
                    yield self._store(config, metric, "failed", error=f"{type(refs).__name__}: {refs}")
                    continue
                task = self._task(config, metric, refs)
                if metric.name not in self.shared and not any(t.metric == metric.name for t in tasks):
                    firsts.add(id(task))
                tasks.append(task)
        # The first task of each metric computes what the originals give (once per run); the
        # metric's other tasks wait for it and start from what it computed -- each as soon as its
        # own metric's first task is back, so a free worker never waits on a whole batch.
        settled = set(self.shared)

        def ready(task: SequenceTask) -> bool:
            return id(task) in firsts or task.metric in settled

        def prepare(task: SequenceTask) -> SequenceTask:
            return replace(task, shared=dict(self.shared.get(task.metric, {})))

        for result in executor.map(TaskQueue(tasks, ready, prepare)):
            metric = by_name[result.metric]
            if result.status == "ok" and result.shared:
                self.shared.setdefault(metric.name, {}).update(result.shared)
            settled.add(metric.name)  # failed or not: the others compute it themselves then
            yield self._store(result.config, metric, result.status, result.metrics, result.extra, result.error)

    def _task(self, config: CodecConfig, metric: SequenceMetric, refs: PayloadRefs) -> SequenceTask:
        return SequenceTask(self.dataset_spec, config, metric.name, tuple(self.frame_indices), self.seed, refs,
                            dict(self.shared.get(metric.name, {})))

    def _store(self, config: CodecConfig, metric: SequenceMetric, status: str, values: dict | None = None,
               extra: dict | None = None, error: str | None = None) -> ResultRow:
        row = self.rows.sequence_row(config, metric, status, values or {}, extra or {}, error)
        self.store.put(row)
        return row
