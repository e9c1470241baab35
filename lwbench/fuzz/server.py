"""Decoding crafted payloads out of process, measured: the fuzzer's :class:`DecodeServer`.

The child (a :class:`lwbench.sandbox.Sandbox`, as the run's workers) decodes one case at a time
with one thread and a memory ceiling (a bomb becomes a ``MemoryError`` instead of eating the
machine); a case that takes longer than a generous wall-clock timeout kills and replaces it.
Each case's CPU time and peak memory (``VmHWM``, reset per case) are measured, and what the
decoder returned is judged:

- ``ok``: a finite float32 ``(M, 3)`` cloud within reach -- no point farther from the sensor
  than the payload's sensor sees (its max range plus :data:`lwbench.limits.RANGE_MARGIN`), for a
  codec whose payloads name their sensor (its valid seed payload does); else, or when that
  sensor cannot be resolved, than :data:`lwbench.limits.MAX_COORDINATE`;
- ``PayloadError``: refused, as the contract asks;
- ``absurd``: a cloud no LiDAR returns (the points beyond that reach) -- a failure;
- ``bad output``, an exception type's name, ``memory``, ``timeout``, ``crash``: failures.
"""

from __future__ import annotations

import importlib
import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lwbench.sandbox import Sandbox, cap_memory, enter_child, reset_peak, status_mb

__all__ = ["CPU_LIMIT_S", "MEMORY_LIMIT_MB", "DecodeServer", "Outcome", "class_ref", "shared_server"]

CPU_LIMIT_S = 1.0  # no decode over a second of CPU ...
MEMORY_LIMIT_MB = 512  # ... or 512 MB above what the process held before it
_TIMEOUT_S = 20.0  # wall clock per case before the child is killed (generous: a shared machine)
_CEILING_MB = 1536  # RLIMIT_DATA above the warm child: a bomb fails instead of swapping
_START_S = 300.0  # the child's start-up (imports) is not a case's time


@dataclass(frozen=True)
class Outcome:
    """What one decode did: ``kind`` is ``ok``, ``PayloadError``, ``absurd`` (a cloud beyond any
    LiDAR's reach), an exception type's name, ``bad output``, ``memory`` (a ``MemoryError``,
    possibly wrapped), ``timeout`` or ``crash``."""

    kind: str
    cpu_s: float = 0.0
    peak_mb: float = 0.0
    message: str = ""

    @property
    def verdict(self) -> str:
        """``fine`` or what broke the contract (the kind, ``over 1 s`` or ``over 512 MB``)."""
        if self.kind not in ("ok", "PayloadError"):
            return self.kind
        if self.cpu_s > CPU_LIMIT_S:
            return "over 1 s"
        if self.peak_mb > MEMORY_LIMIT_MB:
            return "over 512 MB"
        return "fine"


def _memory_cause(exc: BaseException) -> bool:
    seen = exc
    while seen is not None:
        if isinstance(seen, MemoryError) or "can't allocate memory" in str(seen):
            return True
        seen = seen.__context__ or seen.__cause__
    return False


def _resolve(ref: str) -> type:
    module, _, qual = ref.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def class_ref(cls: type) -> str:
    """``module:qualname`` of a codec class, importable in a child process."""
    return f"{cls.__module__}:{cls.__qualname__}"


def _named_sensor(data: bytes | None, sensors):
    from lwbench.payload import Payload
    from lwbench.sensors.model import SensorModel

    try:
        wire = Payload.from_bytes(data).meta.get("sensor")
        return SensorModel.from_wire(wire, sensors) if isinstance(wire, dict) else None
    except Exception:  # noqa: BLE001 - a sensor the payload cannot name
        return None


def reach_of(data: bytes, seed: bytes | None, sensors) -> tuple[float, str]:
    """How far from the sensor a decode of ``data`` may put a point, and why: when the codec's
    payloads name their sensor (``seed``, the valid payload ``data`` was made from, does), that
    sensor's max range plus the margin -- the case's own sensor, else the seed's; otherwise the
    ceiling (a decoder that does not read a sensor is not held to one a mutation slipped in)."""
    from lwbench.limits import coordinate_bound

    original = _named_sensor(seed, sensors) if seed is not None else None
    if original is not None:
        sensor = _named_sensor(data, sensors) or original
        declared = _declared_reach(data)
        if declared is not None and declared > sensor.max_range:
            return coordinate_bound(declared), f"its header declares returns to {declared:g} m"
        return coordinate_bound(sensor.max_range), f"its sensor sees to {sensor.max_range:g} m"
    return coordinate_bound(None), "no LiDAR return is that far"


def _declared_reach(data: bytes) -> float | None:
    """A payload's own ``reach_m`` (the farthest return its encoder saw, e.g. rangeimage's, which
    keeps returns past its sensor model's max range): the header bound its decoder enforces."""
    from lwbench.payload import Payload

    try:
        reach = Payload.from_bytes(data).meta.get("reach_m")
    except Exception:  # noqa: BLE001 - a payload that does not parse declares nothing
        return None
    return float(reach) if isinstance(reach, (int, float)) and not isinstance(reach, bool) and reach > 0 else None


def judge(out: object, data: bytes, sensors, seed: bytes | None = None) -> tuple[str, str]:
    """``(kind, message)`` of what a decoder returned for ``data`` (see the module docstring)."""
    arr = np.asarray(out)
    if not (isinstance(out, np.ndarray) and arr.ndim == 2 and arr.shape[1] == 3 and arr.dtype == np.float32
            and np.isfinite(arr).all()):
        return "bad output", f"{type(out).__name__} {getattr(arr, 'shape', '')} {arr.dtype}"
    if len(arr):
        limit, why = reach_of(data, seed, sensors)
        far = int((np.linalg.norm(arr.astype(np.float64), axis=1) > limit).sum())
        if far:
            return "absurd", f"{far} of {len(arr)} points farther than {limit:g} m ({why})"
    return "ok", ""


def _serve(conn, parent: int, ceiling_mb: int) -> None:  # the child
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    enter_child(parent)
    import torch

    from lwbench.errors import PayloadError
    from lwbench.sensors.catalog import SensorCatalog
    from lwbench.sensors.model import SensorModel

    torch.set_num_threads(1)
    cap_memory(ceiling_mb)  # set before any decode: a bomb fails instead of eating the machine
    classes: dict[str, type] = {}
    sensors = SensorCatalog()  # what the campaign says its payloads may name
    conn.send(("ready",))
    while True:
        msg = conn.recv()
        if msg is None:
            return
        op, *args = msg
        if op == "sensors":
            sensors.update(SensorModel.from_dict(d) for d in args[0])
            conn.send(("ok",))
            continue
        ref, params, data, warm, seed = args
        cls = classes.get(ref) or classes.setdefault(ref, _resolve(ref))
        if warm:  # imports and first-call set-up, not measured
            try:
                cls(**params).use_sensors(sensors).decode(data)
            except Exception:  # noqa: BLE001, S110 - warm-up only
                pass
            conn.send(("ok",))
            continue
        reset_peak()
        before = status_mb("VmRSS")
        t0 = time.process_time()
        try:
            out = cls(**params).use_sensors(sensors).decode(data)
            cpu = time.process_time() - t0
            kind, message = judge(out, data, sensors, seed)
        except PayloadError as exc:
            cpu = time.process_time() - t0
            kind, message = ("memory" if _memory_cause(exc) else "PayloadError"), str(exc)[:300]
        except BaseException as exc:  # noqa: BLE001 - the point of the harness
            cpu = time.process_time() - t0
            kind, message = ("memory" if _memory_cause(exc) else type(exc).__name__), str(exc)[:300]
        peak = max(0.0, status_mb("VmHWM") - before)
        conn.send((kind, cpu, peak, message))


class DecodeServer:
    """A child process that decodes cases one at a time, replaced when it dies or hangs."""

    def __init__(self, *, timeout_s: float = _TIMEOUT_S, ceiling_mb: int = _CEILING_MB) -> None:
        self.timeout_s, self.ceiling_mb = timeout_s, ceiling_mb
        self._box: Sandbox | None = None
        self._sensors: list[dict] = []
        self._warm: set[tuple[str, str]] = set()
        self.restarts = 0

    def _start(self) -> None:
        self._box = Sandbox(_serve, (self.ceiling_mb,), name="lwbench-fuzz")
        self._box.start(_START_S, "the fuzz decode server")
        self._warm.clear()
        if self._sensors:
            self._box.call(("sensors", self._sensors), _START_S)

    def register_sensors(self, sensors: Sequence[dict]) -> None:
        """Sensor tables the child must know (payloads name derived sensors by id)."""
        self._sensors = list(sensors)
        if self._box is not None and self._box.alive:
            self._box.call(("sensors", self._sensors), 120.0)

    def decode(self, ref: str, params: dict, data: bytes, warm_with: bytes | None = None, *,
               judged_by: bytes | None = None) -> Outcome:
        """Decode the case ``data`` with ``ref(**params)``; ``warm_with`` is the valid payload it
        was made from (decoded once, unmeasured, to warm the decoder up; it also says whether the
        codec's payloads name a sensor, see :func:`reach_of`). ``judged_by`` says the latter
        without the warm-up (a regression case replayed alone: the case itself)."""
        if self._box is None or not self._box.alive:
            self._start()
        key = (ref, json.dumps(params, sort_keys=True, default=str))
        if warm_with is not None and key not in self._warm:
            # Imports and first-call set-up on a valid payload, unmeasured.
            if self._box.call(("decode", ref, params, warm_with, True, None), _START_S) == "died":
                self._kill()
                self._start()
            self._warm.add(key)
        seed = warm_with if judged_by is None else judged_by
        got = self._box.call(("decode", ref, params, data, False, seed), self.timeout_s)
        if isinstance(got, tuple):
            return Outcome(got[0], got[1], got[2], got[3])
        code = self._kill()
        if got == "timeout":
            return Outcome("timeout", self.timeout_s, 0.0, f"no answer within {self.timeout_s:g} s")
        return Outcome("crash", 0.0, 0.0, f"decoder process died (exit code {code})")

    def _kill(self) -> int | None:
        code = self._box.kill()
        self.restarts += 1
        self._box = None
        return code

    def close(self) -> None:
        if self._box is not None:
            self._box.stop()
        self._box = None

    def __enter__(self) -> DecodeServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_SHARED: DecodeServer | None = None


def shared_server() -> DecodeServer:
    """One decode server per process, closed at exit (the conformance kit's fuzz check and the
    tests share it, so the child's start-up -- imports -- is paid once)."""
    global _SHARED
    if _SHARED is None:
        import atexit

        _SHARED = DecodeServer()
        atexit.register(_SHARED.close)
    return _SHARED
