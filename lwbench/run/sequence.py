"""Stage 4 -- sequence metrics: localization, odometry, occupancy over a configuration's frames.

They run per codec configuration once its frames are recorded, on the decoded clouds stored as
artifacts of those frames' evaluations (a cloud missing from the store -- rows recorded by an
older lwbench -- is re-evaluated through the same :class:`~.evaluate.Evaluator` and recorded).
What depends only on the original scans (ground-truth poses, the original occupancy map, the
tracking of the originals) is computed once per dataset and shared by every configuration
through :attr:`SequenceStage.shared`, an explicit cache owned by this stage -- not a hidden
module-level one.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.dataset import Dataset
from lwbench.errors import LwbenchError
from lwbench.measure import Stopwatch
from lwbench.metric import SequenceEvaluation, SequenceMetric
from lwbench.store import ResultRow, ResultStore

from .evaluate import Evaluator, FrameResult
from .plan import CodecConfig
from .record import DECODED, RowFactory, record_frame

__all__ = ["SequenceStage"]


@dataclass
class SequenceStage:
    store: ResultStore
    dataset: Dataset
    frame_indices: list[int]
    rows: RowFactory
    evaluator: Evaluator
    metrics: list[SequenceMetric]
    shared: dict[str, Any] = field(default_factory=dict)
    # How a missing cloud is re-evaluated: the runner sets its executor's; by default in process.
    evaluate: Callable[[int, CodecConfig], FrameResult] | None = None

    def keys(self, configs: list[CodecConfig]) -> list[str]:
        return [self.rows.sequence_row(c, m).key for c in configs for m in self.metrics]

    def decoded_clouds(self, config: CodecConfig) -> tuple[list[np.ndarray], int]:
        """The decoded cloud of every frame of ``config`` and how many frames failed."""
        clouds, failed = [], 0
        for i in self.frame_indices:
            row = self.rows.frame_row(i, config)
            if self.store.status(row.key) == "failed":
                failed += 1
                continue
            cloud = self.store.artifact(row.evaluation, DECODED)
            if cloud is None:
                if self.evaluate is not None:
                    result = self.evaluate(i, config)
                else:
                    (result,) = self.evaluator.evaluate(self.dataset[i], [config], keep_decoded=True)
                record_frame(self.store, self.rows, result)
                if result.status != "ok":
                    failed += 1
                    continue
                cloud = result.decoded
            clouds.append(cloud)
        return clouds, failed

    def run(
        self, configs: list[CodecConfig], todo: Callable[[str], bool], seed: int
    ) -> Iterator[ResultRow]:
        """Compute and store every (configuration, metric) row ``todo`` says is missing."""
        for config in configs:
            pending = [m for m in self.metrics if todo(self.rows.sequence_row(config, m).key)]
            if not pending:
                continue
            try:
                decoded, failed = self.decoded_clouds(config)
                if failed:
                    raise LwbenchError(f"{failed} of {len(self.frame_indices)} frames failed to encode/decode")
            except Exception as exc:  # noqa: BLE001 - every metric of this configuration fails with it
                for metric in pending:
                    yield self._store(config, metric, exc)
                continue
            seq = SequenceEvaluation(
                self.dataset, self.frame_indices, decoded, config.name, config.params, seed, _cache=self.shared
            )
            for metric in pending:
                try:
                    watch = Stopwatch()
                    with watch.time("metric_ms"):
                        values = metric.compute(seq)
                    row = self.rows.sequence_row(config, metric, "ok", values, dict(watch.ms))
                    self.store.put(row)
                    yield row
                except Exception as exc:  # noqa: BLE001
                    yield self._store(config, metric, exc)

    def _store(self, config: CodecConfig, metric: SequenceMetric, exc: BaseException) -> ResultRow:
        row = self.rows.sequence_row(
            config, metric, "failed", {}, {"traceback": traceback.format_exc(limit=6)}, f"{type(exc).__name__}: {exc}"
        )
        self.store.put(row)
        return row
