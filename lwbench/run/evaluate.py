"""Stage 2 -- evaluate: one frame through one codec configuration, scored by every metric.

:meth:`Evaluator.evaluate` is the whole job of a worker: encode, decode the bytes with a
*fresh* codec instance (so nothing but the payload -- and the sensor table the stream carries
once, handed to the decoder from the dataset -- crosses from encoder to decoder), check the
decoded cloud, compute every frame metric.
It returns :class:`FrameResult` values and touches no store: recording is the next stage's job,
so the same function serves the local pool, a cluster executor and the sequence stage's
re-evaluation of a missing cloud.

A codec or metric that raises makes a ``failed`` result carrying the error and the run goes on.
Warm-up: the first time an evaluator meets a configuration it encodes and decodes once untimed
(lazy imports, JIT, allocator growth); those times go to ``extra`` as ``warmup_*_ms``, never
into the steady-state metrics. For selection codecs ``encode_ms`` is the whole encode --
``select`` plus the shared serializer (``select_ms`` and ``serialize_ms`` are its parts).
"""

from __future__ import annotations

import traceback
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.codec import Codec, SelectionCodec
from lwbench.errors import DecodeError, LwbenchError, MissingDependencyError, PayloadError
from lwbench.frame import Frame
from lwbench.limits import checked_cloud
from lwbench.measure import PeakMemory, Stopwatch
from lwbench.metric import Evaluation
from lwbench.reference import reference_ms
from lwbench.registry import Registry

from .plan import CodecConfig

__all__ = ["FrameResult", "Evaluator", "Encoded", "decoded_cloud", "encode_decode"]


@dataclass
class FrameResult:
    """The outcome of one (frame, configuration): metrics, or the error that stopped it."""

    frame: int
    config: CodecConfig
    status: str  # "ok" | "failed"
    metrics: dict[str, float | None] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    decoded: np.ndarray | None = None  # kept only when the caller asked for it (a report's gallery)
    payload: bytes | None = None  # kept when a later stage re-decodes it (the sequence metrics)

    @classmethod
    def failure(cls, frame: int, config: CodecConfig, exc: BaseException, extra: dict | None = None) -> FrameResult:
        return cls(frame, config, "failed", extra=extra or {}, error=f"{type(exc).__name__}: {exc}")


@dataclass
class Encoded:
    """What one timed encode + decode produced."""

    payload: bytes
    decoded: np.ndarray
    timings_ms: dict[str, float]
    peak_mb: float | None
    device: str


def _device_of(codec: Codec) -> str:
    name = codec.config.get("device")
    if name is None:
        return "cpu"
    from lwbench.device import resolve_device

    return str(resolve_device(name))


def encode_decode(codec_cls: type[Codec], config: CodecConfig, encoder: Codec, frame: Frame) -> Encoded:
    """Encode with ``encoder``, decode the bytes with a fresh instance; timed, memory-measured."""
    watch = Stopwatch()
    device = _device_of(encoder)
    with PeakMemory(cuda=device.startswith("cuda")) as mem:
        if isinstance(encoder, SelectionCodec):
            with watch.time("select_ms"):
                indices = encoder.select(frame)
            with watch.time("serialize_ms"):
                payload = encoder.encode_selected(frame, indices)
            watch.ms["encode_ms"] = watch.ms["select_ms"] + watch.ms["serialize_ms"]
        else:
            with watch.time("encode_ms"):
                payload = encoder.encode(frame)
        if not isinstance(payload, (bytes, bytearray)):
            raise LwbenchError(f"{config.name}: encode returned {type(payload).__name__}, not bytes")
        # The receiver knows the stream's sensors (their tables travel once per stream, not per
        # frame): the decoder is handed the dataset's sensor for this frame and the tables the
        # encoder's payloads named -- what a stream header carries -- and nothing else.
        decoder = codec_cls(**config.params).use_sensors([frame.sensor, *encoder.sensors])
        with watch.time("decode_ms"):
            decoded = decoder.decode(bytes(payload))
    return Encoded(bytes(payload), decoded_cloud(config.name, decoded), watch.ms, mem.peak_mb, device)


def decoded_cloud(codec: str, decoded: object) -> np.ndarray:
    """A decoder's output as every receiver -- the runner, ``lwbench decode``, the stream's base --
    takes it: :func:`lwbench.checked_cloud`'s checks, a breach blamed on the codec (``DecodeError``:
    its decoder let through what it should have refused as a ``PayloadError``)."""
    try:
        return checked_cloud(decoded, codec)
    except PayloadError as exc:
        raise DecodeError(f"{codec}: decode returned what no decoder may return ({exc})") from None


class Evaluator:
    """Per-process evaluation state: the configured frame metrics and warm encoders.

    One per process (built once per worker, not per task), so warm-up happens once per
    configuration per process.
    """

    def __init__(self, registry: Registry, metric_params: dict[str, dict] | None = None) -> None:
        self.registry = registry
        self.metrics = registry.frame_metric_instances(metric_params)
        self.scoring = [m.signature() for m in self.metrics]
        self._encoders: dict[str, Codec] = {}

    def encoded(self, frame: Frame, config: CodecConfig) -> tuple[Encoded, dict[str, Any]]:
        """The timed encode/decode (after a warm-up pass the first time), and warm-up extras."""
        codec_cls = self.registry.codec(config.name)
        extra: dict[str, Any] = {}
        encoder = self._encoders.get(config.key)
        if encoder is None:
            encoder = self._encoders[config.key] = codec_cls(**config.params)
            warm = encode_decode(codec_cls, config, encoder, frame)
            extra.update({f"warmup_{k}": v for k, v in warm.timings_ms.items()})
        return encode_decode(codec_cls, config, encoder, frame), extra

    def evaluate(
        self, frame: Frame, configs: Sequence[CodecConfig], *, keep_decoded: bool = False, keep_payload: bool = False
    ) -> list[FrameResult]:
        """Every configuration on one frame; the frame's k-d trees and normals are shared."""
        return list(self.evaluate_each(frame, configs, keep_decoded=keep_decoded, keep_payload=keep_payload))

    def evaluate_each(
        self, frame: Frame, configs: Sequence[CodecConfig], *, keep_decoded: bool = False, keep_payload: bool = False
    ) -> Iterator[FrameResult]:
        """:meth:`evaluate`, one result at a time (a worker process reports each as it is done,
        so a configuration that hangs or kills the process loses only its own result)."""
        shared: dict[str, Any] = {}
        for config in configs:
            yield self._one(frame, config, shared, keep_decoded, keep_payload)

    def _one(self, frame: Frame, config: CodecConfig, shared: dict[str, Any], keep_decoded: bool,
             keep_payload: bool = False) -> FrameResult:
        extra: dict[str, Any] = {}
        try:
            if len(frame) == 0:
                raise LwbenchError(f"frame {frame.index} is empty (no returns)")
            enc, extra = self.encoded(frame, config)
            extra["device"] = enc.device
            # This process's time of the fixed reference workload: a board shows runtimes as
            # multiples of it (lwbench.reference), comparable across machines.
            extra["reference_ms"] = reference_ms()
            extra.update({k: v for k, v in enc.timings_ms.items() if k == "serialize_ms"})
            kind = self.registry.codec(config.name).kind
            ev = Evaluation(frame, enc.payload, enc.decoded, kind, enc.timings_ms, enc.peak_mb, enc.device, shared)
            values: dict[str, float | None] = {}
            watch = Stopwatch()
            with watch.time("metrics_ms"):
                for m in self.metrics:
                    try:
                        values.update(m.compute(ev))
                    except MissingDependencyError:
                        raise
                    except Exception as exc:  # noqa: BLE001 - a metric's bug fails the row, not the run
                        raise LwbenchError(f"metric {m.name}: {type(exc).__name__}: {exc}") from exc
            extra.update(watch.ms)
            return FrameResult(frame.index, config, "ok", values, extra, None, enc.decoded if keep_decoded else None,
                               enc.payload if keep_payload else None)
        except MissingDependencyError:
            raise  # the machine, not the codec: stop the run with the install hint, record nothing
        except Exception as exc:  # noqa: BLE001 - the failure is the result
            extra["traceback"] = traceback.format_exc(limit=6)
            return FrameResult.failure(frame.index, config, exc, extra)
