"""The runner: codecs x parameter values x frames -> one stored row each.

For every (frame, codec configuration) it encodes, decodes the bytes with a *fresh* codec
instance (so nothing but the payload crosses from encoder to decoder), scores the result with
every registered frame metric and stores the row at once. A codec or metric that raises
becomes a ``failed`` row with its error and the run continues. Keys already in the store are
skipped, which is what makes an interrupted run resumable and a repeated command free.

With poses in the dataset, sequence metrics (localization, occupancy) run per configuration
after its frames, on the decoded clouds kept in a side folder next to the store.

Warm-up: the first frame a process evaluates for a configuration is encoded and decoded once
untimed before the timed pass (lazy imports, JIT, allocator growth); that pass's times are kept
in the row's ``extra`` as ``warmup_*_ms`` and never mixed into the steady-state metrics.
"""

from __future__ import annotations

import itertools
import os
import traceback
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np

from lwbench.codec import Codec, SelectionCodec
from lwbench.dataset import Dataset
from lwbench.errors import DecodeError, LwbenchError, ParameterError
from lwbench.measure import PeakMemory, Stopwatch
from lwbench.metric import Evaluation, SequenceEvaluation, SequenceMetric
from lwbench.registry import Registry, get_registry
from lwbench.sensor import register_sensor
from lwbench.store import ResultRow, ResultStore, canonical_json, environment_versions, machine_description
from lwbench.types import Frame, resolve_params

__all__ = ["CodecConfig", "DatasetSpec", "RunSummary", "Runner", "expand_codec_configs"]


@dataclass(frozen=True)
class DatasetSpec:
    """How to build a dataset: registry name + parameters (picklable, for worker processes)."""

    name: str
    params: dict[str, Any]

    def build(self, registry: Registry) -> Dataset:
        return registry.dataset(self.name)(**self.params)

    @property
    def label(self) -> str:
        if "path" in self.params and self.params["path"]:
            return str(self.params["path"])
        shown = ",".join(f"{k}={v}" for k, v in sorted(self.params.items()))
        return f"{self.name}({shown})" if shown else self.name


@dataclass(frozen=True)
class CodecConfig:
    """One codec with fully resolved parameters: the unit a leaderboard line describes."""

    name: str
    params: dict[str, Any]

    @property
    def label(self) -> str:
        return f"{self.name}({','.join(f'{k}={v}' for k, v in sorted(self.params.items()))})"

    @property
    def key(self) -> str:
        return f"{self.name}:{canonical_json(self.params)}"


def expand_codec_configs(codec_cls: type[Codec], values: Mapping[str, Sequence[str]], seed: int) -> list[CodecConfig]:
    """The cartesian product of the given parameter values, each resolved and validated.

    A codec that declares ``seed`` and is not given one gets the run's seed, so one ``--seed``
    controls every random choice of a run.
    """
    declared = {p.name for p in codec_cls.all_params()}
    unknown = sorted(set(values) - declared)
    if unknown:
        raise ParameterError(
            f"{codec_cls.name}: unknown parameter(s) {', '.join(unknown)}; "
            f"known: {', '.join(sorted(declared)) or '(none)'}"
        )
    names = sorted(values)
    configs = []
    for combo in itertools.product(*(values[n] for n in names)):
        given: dict[str, Any] = dict(zip(names, combo, strict=True))
        if "seed" in declared and "seed" not in given:
            given["seed"] = seed
        params = resolve_params(codec_cls.name, codec_cls.all_params(), given)
        configs.append(CodecConfig(codec_cls.name, params))
    return configs


@dataclass
class RunSummary:
    evaluated: int = 0
    skipped: int = 0
    failed: int = 0
    sequence_rows: int = 0
    interrupted: bool = False
    failures: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------------------------
# Evaluating one frame (runs in the main process or in a worker)
# --------------------------------------------------------------------------------------------


def _device_of(codec: Codec) -> str:
    name = codec.config.get("device")
    if name is None:
        return "cpu"
    from lwbench.device import resolve_device

    return str(resolve_device(name))


def _encode_decode(codec_cls: type[Codec], config: CodecConfig, encoder: Codec, frame: Frame):
    watch = Stopwatch()
    device = _device_of(encoder)
    with PeakMemory(cuda=device.startswith("cuda")) as mem:
        if isinstance(encoder, SelectionCodec):
            with watch.time("select_ms"):
                indices = encoder.select(frame)
            with watch.time("encode_ms"):
                payload = encoder.encode_selected(frame, indices)
        else:
            with watch.time("encode_ms"):
                payload = encoder.encode(frame)
        if not isinstance(payload, (bytes, bytearray)):
            raise LwbenchError(f"{config.name}: encode returned {type(payload).__name__}, not bytes")
        # The receiver knows the stream's sensor (its table travels once per stream, not per frame).
        register_sensor(frame.sensor)
        decoder = codec_cls(**config.params)  # fresh: only the bytes (and that table) cross over
        with watch.time("decode_ms"):
            decoded = decoder.decode(bytes(payload))
    decoded = np.asarray(decoded)
    if decoded.ndim != 2 or decoded.shape[1] != 3 or not np.issubdtype(decoded.dtype, np.floating):
        raise DecodeError(f"{config.name}: decode returned shape {decoded.shape}, expected (M, 3)")
    if not np.isfinite(decoded).all():
        raise DecodeError(f"{config.name}: decode returned NaN/inf coordinates")
    return bytes(payload), decoded.astype(np.float32, copy=False), watch.ms, mem.peak_mb, device


@dataclass
class _WorkerState:
    registry: Registry
    datasets: dict[str, Dataset] = field(default_factory=dict)
    encoders: dict[str, Codec] = field(default_factory=dict)
    metric_params: dict[str, dict] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.metrics = self.registry.frame_metric_instances(self.metric_params)
        self.scoring = [m.signature() for m in self.metrics]


def evaluate_frame(
    state: _WorkerState,
    spec: DatasetSpec,
    dataset_id: str,
    frame_index: int,
    configs: list[CodecConfig],
    seed: int,
    decoded_dir: str | None,
) -> Iterator[ResultRow]:
    """All requested configurations on one frame, one row at a time (so the caller can store
    each as soon as it exists); the frame's KD-tree, normals and range image are shared."""
    registry = state.registry
    try:
        dataset = state.datasets.get(spec.label) or state.datasets.setdefault(spec.label, spec.build(registry))
        frame = dataset[frame_index]
    except Exception as exc:  # noqa: BLE001 - a bad scan fails its rows, not the run
        err = f"loading frame {frame_index}: {type(exc).__name__}: {exc}"
        for cfg in configs:
            yield _row(spec, dataset_id, frame_index, cfg, state, seed, "failed", {}, {}, err)
        return
    frame_cache: dict[str, Any] = {}
    metrics = state.metrics
    for cfg in configs:
        codec_cls = registry.codec(cfg.name)
        extra: dict[str, Any] = {}
        try:
            if len(frame) == 0:
                raise LwbenchError(f"frame {frame_index} is empty (no returns)")
            encoder = state.encoders.get(cfg.key)
            if encoder is None:
                encoder = state.encoders[cfg.key] = codec_cls(**cfg.params)
                _, _, warm_ms, _, _ = _encode_decode(codec_cls, cfg, encoder, frame)
                extra.update({f"warmup_{k}": v for k, v in warm_ms.items()})
            payload, decoded, timings, peak_mb, device = _encode_decode(codec_cls, cfg, encoder, frame)
            extra["device"] = device
            ev = Evaluation(frame, payload, decoded, codec_cls.kind, timings, peak_mb, device, frame_cache)
            values: dict[str, float | None] = {}
            watch = Stopwatch()
            with watch.time("metrics_ms"):
                for m in metrics:
                    try:
                        values.update(m.compute(ev))
                    except Exception as exc:  # noqa: BLE001
                        raise LwbenchError(f"metric {m.name}: {type(exc).__name__}: {exc}") from exc
            extra.update(watch.ms)
            row = _row(spec, dataset_id, frame_index, cfg, state, seed, "ok", values, extra, None)
            if decoded_dir is not None:
                np.save(Path(decoded_dir) / f"{row.evaluation}.npy", decoded)
        except Exception as exc:  # noqa: BLE001 - the failure is the result
            extra["traceback"] = traceback.format_exc(limit=6)
            err = f"{type(exc).__name__}: {exc}"
            row = _row(spec, dataset_id, frame_index, cfg, state, seed, "failed", {}, extra, err)
        yield row


def _row(spec, dataset_id, frame_index, cfg, state: _WorkerState, seed, status, metrics, extra, error) -> ResultRow:
    registry = state.registry
    codec_cls = registry.codec(cfg.name)
    return ResultRow(
        kind="frame",
        dataset=spec.label,
        dataset_id=dataset_id,
        frame=frame_index,
        codec=cfg.name,
        codec_version=codec_cls.version,
        params=cfg.params,
        status=status,
        metrics=metrics,
        seed=seed,
        error=error,
        extra=extra,
        versions={**_VERSIONS, "plugin": registry.providers.get(("codec", cfg.name), "?")},
        machine=_MACHINE,
        plugin_version=registry.plugin_version("codec", cfg.name),
        scoring=state.scoring,
    )


_VERSIONS: dict[str, str] = {}
_MACHINE = ""
_STATE: _WorkerState | None = None


def _init_worker(threads: int, metric_params: dict[str, dict]) -> None:
    global _STATE, _VERSIONS, _MACHINE
    import torch

    torch.set_num_threads(threads)
    _STATE = _WorkerState(get_registry(), metric_params=metric_params)
    _VERSIONS = environment_versions()
    _MACHINE = machine_description()


def _worker_task(args: tuple) -> list[ResultRow]:
    assert _STATE is not None
    return list(evaluate_frame(_STATE, *args))


# --------------------------------------------------------------------------------------------
# The run
# --------------------------------------------------------------------------------------------


class Runner:
    def __init__(
        self,
        store: ResultStore,
        dataset: DatasetSpec,
        configs: list[CodecConfig],
        *,
        frames: int | None = None,
        seed: int = 0,
        workers: int = 1,
        sequence_metrics: bool = True,
        retry_failed: bool = False,
        force: bool = False,
        metric_params: dict[str, dict] | None = None,
        registry: Registry | None = None,
    ) -> None:
        self.store = store
        self.spec = dataset
        self.configs = configs
        self.seed = seed
        self.workers = max(1, workers)
        self.retry_failed = retry_failed
        self.force = force
        self.metric_params = metric_params or {}
        self.registry = registry or get_registry()
        self.state = _WorkerState(self.registry, metric_params=self.metric_params)
        self.sequence_metric_list = self.registry.sequence_metric_instances(self.metric_params)
        self.dataset = dataset.build(self.registry)
        self.dataset_id = self.dataset.identity()
        n = len(self.dataset)
        self.frame_indices = list(range(min(n, frames) if frames else n))
        self.sequence_metrics = sequence_metrics and self.dataset.has_poses and bool(self.registry.sequence_metrics)
        self.decoded_dir: Path | None = None
        if self.sequence_metrics:
            self.decoded_dir = store.path.with_name(store.path.name + ".decoded")
            self.decoded_dir.mkdir(exist_ok=True)

    def _frame_row(self, frame_index: int, cfg: CodecConfig) -> ResultRow:
        return _row(self.spec, self.dataset_id, frame_index, cfg, self.state, self.seed, "ok", {}, {}, None)

    def _frame_key(self, frame_index: int, cfg: CodecConfig) -> str:
        return self._frame_row(frame_index, cfg).key

    def _todo(self, key: str) -> bool:
        if self.force:
            return True
        status = self.store.status(key)
        return status is None or (status == "failed" and self.retry_failed)

    def keys(self) -> set[str]:
        """Keys of every row this run asks for (frame rows and, with poses, sequence rows)."""
        out = {self._frame_key(i, c) for i in self.frame_indices for c in self.configs}
        if self.sequence_metrics:
            out |= {self._sequence_row(c, m, "ok", {}, {}).key for c in self.configs for m in self.sequence_metric_list}
        return out

    def pending(self) -> list[tuple[int, list[CodecConfig]]]:
        tasks = []
        for i in self.frame_indices:
            cfgs = [c for c in self.configs if self._todo(self._frame_key(i, c))]
            if cfgs:
                tasks.append((i, cfgs))
        return tasks

    def run(self, on_progress: Callable[[int, int, ResultRow | None], None] | None = None) -> RunSummary:
        """Evaluate what is not stored yet. ``on_progress(done, total, row)`` after each row."""
        global _VERSIONS, _MACHINE
        _VERSIONS = _VERSIONS or environment_versions()
        _MACHINE = _MACHINE or machine_description()
        summary = RunSummary()
        tasks = self.pending()
        total = sum(len(c) for _, c in tasks)
        summary.skipped = len(self.frame_indices) * len(self.configs) - total
        done = 0
        decoded_dir = str(self.decoded_dir) if self.decoded_dir else None

        def record(rows: Iterable[ResultRow]) -> None:
            nonlocal done
            for row in rows:
                self.store.put(row)
                done += 1
                summary.evaluated += 1
                if row.status == "failed":
                    summary.failed += 1
                    summary.failures.append(f"{row.codec} frame {row.frame}: {row.error}")
                if on_progress:
                    on_progress(done, total, row)

        args = [(self.spec, self.dataset_id, i, cfgs, self.seed, decoded_dir) for i, cfgs in tasks]
        try:
            if self.workers == 1 or len(args) <= 1:
                state = self.state
                state.datasets.setdefault(self.spec.label, self.dataset)
                for a in args:
                    record(evaluate_frame(state, *a))
            else:
                threads = max(1, (os.cpu_count() or 1) // self.workers)
                with ProcessPoolExecutor(
                    self.workers,
                    mp_context=get_context("spawn"),
                    initializer=_init_worker,
                    initargs=(threads, self.metric_params),
                ) as pool:
                    futures = [pool.submit(_worker_task, a) for a in args]
                    for fut in as_completed(futures):
                        record(fut.result())
            if self.sequence_metrics:
                summary.sequence_rows = self._run_sequence_metrics(summary)
        except KeyboardInterrupt:
            summary.interrupted = True
        return summary

    # -- sequence metrics ------------------------------------------------------------------
    def _run_sequence_metrics(self, summary: RunSummary) -> int:
        stored = 0
        for cfg in self.configs:
            for metric in self.sequence_metric_list:
                name = metric.name
                row = self._sequence_row(cfg, metric, "ok", {}, {})
                if not self._todo(row.key):
                    continue
                try:
                    decoded, failed = self._decoded_sequence(cfg)
                    if failed:
                        raise LwbenchError(f"{failed} of {len(self.frame_indices)} frames failed to encode/decode")
                    seq = SequenceEvaluation(self.dataset, self.frame_indices, decoded, cfg.name, cfg.params, self.seed)
                    watch = Stopwatch()
                    with watch.time("metric_ms"):
                        values = metric.compute(seq)
                    row = self._sequence_row(cfg, metric, "ok", values, dict(watch.ms))
                except Exception as exc:  # noqa: BLE001
                    row = self._sequence_row(
                        cfg,
                        metric,
                        "failed",
                        {},
                        {"traceback": traceback.format_exc(limit=6)},
                        f"{type(exc).__name__}: {exc}",
                    )
                    summary.failed += 1
                    summary.failures.append(f"{cfg.name} sequence metric {name}: {row.error}")
                self.store.put(row)
                stored += 1
        return stored

    def _sequence_row(self, cfg, metric: SequenceMetric, status, metrics, extra, error=None) -> ResultRow:
        return ResultRow(
            kind="sequence",
            dataset=self.spec.label,
            dataset_id=self.dataset_id,
            frame=-1,
            codec=cfg.name,
            codec_version=self.registry.codec(cfg.name).version,
            params=cfg.params,
            status=status,
            metrics=metrics,
            seed=self.seed,
            error=error,
            extra=extra,
            part=metric.name,
            versions={**_VERSIONS, "plugin": self.registry.providers.get(("codec", cfg.name), "?")},
            machine=_MACHINE,
            plugin_version=self.registry.plugin_version("codec", cfg.name),
            scoring=[metric.signature()],
        )

    def _decoded_sequence(self, cfg: CodecConfig) -> tuple[list[np.ndarray], int]:
        """Decoded clouds of every frame, from the side folder; frames whose file is missing
        (stored by an older run) are re-encoded here."""
        assert self.decoded_dir is not None
        clouds, failed = [], 0
        state = self.state
        for i in self.frame_indices:
            row = self._frame_row(i, cfg)
            if self.store.status(row.key) == "failed":
                failed += 1
                continue
            path = self.decoded_dir / f"{row.evaluation}.npy"
            if not path.exists():
                frame = self.dataset[i]
                codec_cls = self.registry.codec(cfg.name)
                encoder = state.encoders.setdefault(cfg.key, codec_cls(**cfg.params))
                _, decoded, _, _, _ = _encode_decode(codec_cls, cfg, encoder, frame)
                np.save(path, decoded)
            clouds.append(np.load(path, allow_pickle=False))
        return clouds, failed
