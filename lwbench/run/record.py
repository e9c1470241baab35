"""Stage 3 -- record: results become stored rows with their provenance, and their keys.

A row's key says exactly what produced it: the data (dataset identity, frame), the code (codec
name, version, the package release that provided it), the codec parameters and seed -- the
*evaluation* -- plus how it was scored (every metric's name, version, parameters and settings).
Provenance (lwbench, library versions, machine) is measured once per run and handed around as a
:class:`Provenance` object; nothing here reads module globals.

Artifacts, stored with the row (same transaction) under the evaluation key, so re-scoring with
another metric version reuses them: the *payload* when the sequence metrics will re-decode it
(bytes on the wire: 4 kB a VSGP frame, where its decoded cloud is 1.4 MB), and the decoded cloud
only where a report shows it (the first frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.registry import Registry
from lwbench.results.store import ResultRow, ResultStore, environment_versions, machine_description

from .evaluate import FrameResult
from .plan import CodecConfig

__all__ = ["Provenance", "RowFactory", "DECODED", "ORIGINAL", "PAYLOAD", "original_key", "record_original"]

DECODED = "decoded"  # artifact name of a decoded cloud (kept for a report's gallery frame)
PAYLOAD = "payload"  # artifact name of a payload's bytes (uint8), what the sequence stage re-decodes
ORIGINAL = "points"  # artifact name of an original scan (under original_key)


def original_key(dataset_id: str, frame: int) -> str:
    """Where the original scan of a frame is kept when a report will show it."""
    return f"original:{dataset_id}:{frame}"


@dataclass(frozen=True)
class Provenance:
    """Where and with what a run's numbers were produced."""

    versions: dict[str, str]
    machine: str

    @classmethod
    def current(cls, machine: str | None = None) -> Provenance:
        """This process's versions, and ``machine``: the label a user gave (``--machine``,
        ``LWBENCH_MACHINE``: what tells two teams' rows apart on a common board), else the
        machine's own description (host, architecture, CPUs, system)."""
        import os

        label = machine or os.environ.get("LWBENCH_MACHINE") or machine_description()
        return cls(environment_versions(), label)


@dataclass
class RowFactory:
    """Builds the rows (and so the keys) of one dataset's evaluations."""

    registry: Registry
    dataset_label: str
    dataset_id: str
    seed: int
    scoring: list
    provenance: Provenance
    # The dataset's sensor model is a guess (``Dataset.sensor_guessed``): every row says so.
    sensor_guessed: bool = False
    _defaults: dict[str, dict] = field(default_factory=dict)

    def _common(self, config: CodecConfig) -> dict[str, Any]:
        codec_cls = self.registry.codec(config.name)
        if config.name not in self._defaults:
            self._defaults[config.name] = {p.name: p.default for p in codec_cls.all_params()}
        return {
            "dataset": self.dataset_label,
            "dataset_id": self.dataset_id,
            "codec": config.name,
            "codec_version": codec_cls.version,
            "params": config.params,
            "seed": self.seed,
            "versions": {**self.provenance.versions, "plugin": self.registry.providers.get(("codec", config.name))},
            "machine": self.provenance.machine,
            "plugin_version": self.registry.plugin_version("codec", config.name),
            "sensor_guessed": self.sensor_guessed,
        }

    def frame_row(self, frame: int, config: CodecConfig, result: FrameResult | None = None) -> ResultRow:
        """The row of ``result`` -- or, without one, the row's identity (for its key)."""
        extra = dict(result.extra) if result else {}
        extra["declared_defaults"] = self._declared(config)
        return ResultRow(
            kind="frame",
            frame=frame,
            status=result.status if result else "ok",
            metrics=result.metrics if result else {},
            error=result.error if result else None,
            extra=extra,
            scoring=self.scoring,
            **self._common(config),
        )

    def sequence_row(
        self,
        config: CodecConfig,
        metric,
        status: str = "ok",
        metrics: dict | None = None,
        extra: dict | None = None,
        error: str | None = None,
    ) -> ResultRow:
        return ResultRow(
            kind="sequence",
            frame=-1,
            status=status,
            metrics=metrics or {},
            error=error,
            extra={**(extra or {}), "declared_defaults": self._declared(config)},
            part=metric.name,
            scoring=[metric.signature()],
            **self._common(config),
        )

    def _declared(self, config: CodecConfig) -> dict:
        # The codec's declared defaults travel with the row, so a leaderboard read on a machine
        # without the plugin labels configurations exactly as one with it.
        if config.name not in self._defaults:
            self._common(config)
        return self._defaults[config.name]


def record_frame(store: ResultStore, rows: RowFactory, result: FrameResult) -> ResultRow:
    """Store one frame result (with its payload and decoded cloud, if they were kept) and return its row."""
    row = rows.frame_row(result.frame, result.config, result)
    artifacts: dict = {}
    if result.status == "ok":
        if result.decoded is not None:
            artifacts[DECODED] = result.decoded
        if result.payload is not None:
            artifacts[PAYLOAD] = np.frombuffer(result.payload, dtype=np.uint8)
    store.put(row, artifacts or None)
    return row


def record_original(store: ResultStore, dataset_id: str, frame: int, points) -> None:
    """Keep an original scan beside the decoded clouds of its frame (what a gallery compares)."""
    key = original_key(dataset_id, frame)
    if store.artifact(key, ORIGINAL) is None:
        store.put_artifact(key, ORIGINAL, points)
