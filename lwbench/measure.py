"""Measuring calls: wall time and peak memory.

Peak memory is the growth of the process's resident high-water mark during the measured
block. On Linux, writing ``5`` to ``/proc/self/clear_refs`` resets ``VmHWM`` to the current
RSS, so the peak of *this* block is readable without a sampling thread and includes memory
that ``tracemalloc`` cannot see (torch, Open3D, BLAS). Elsewhere the value is ``None``. When a
CUDA device is in use, the peak of torch's CUDA allocator is added.

The free memory the C heap still holds is handed back first (``malloc_trim``): without that a
block's arrays came from memory earlier frames had freed, and ``raw`` -- which allocates its
payload and a decoded copy of the scan -- read 0 MiB. With it the growth is the block's working
set, what a user means by the memory a codec needs.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["PeakMemory", "Stopwatch", "malloc_trim"]

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")


def _status_kb(field: str) -> int | None:
    try:
        for line in _STATUS.read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` (returns the heap's free pages to the system), None off glibc."""
    with contextlib.suppress(OSError, AttributeError, TypeError):
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    return None


_TRIM = malloc_trim()


class PeakMemory:
    """Context manager; ``.peak_mb`` after exit (``None`` where it cannot be measured)."""

    def __init__(self, cuda: bool = False) -> None:
        self.cuda = cuda
        self.peak_mb: float | None = None
        self._start_kb: int | None = None
        self._resettable = False

    def __enter__(self) -> PeakMemory:
        if _TRIM is not None:
            _TRIM(0)
        try:
            _CLEAR_REFS.write_text("5")
            self._resettable = True
        except OSError:
            self._resettable = False
        self._start_kb = _status_kb("VmRSS")
        if self.cuda:
            import torch

            torch.cuda.reset_peak_memory_stats()
            self._cuda_start = torch.cuda.memory_allocated()
        return self

    def __exit__(self, *exc) -> None:
        hwm = _status_kb("VmHWM")
        if self._resettable and hwm is not None and self._start_kb is not None:
            self.peak_mb = max(0, hwm - self._start_kb) / 1024.0
        if self.cuda:
            import torch

            extra = (torch.cuda.max_memory_allocated() - self._cuda_start) / 2**20
            self.peak_mb = (self.peak_mb or 0.0) + max(0.0, extra)


class Stopwatch:
    """Accumulates named wall times in milliseconds (``perf_counter_ns``)."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    def time(self, name: str):
        return _Lap(self, name)


class _Lap:
    def __init__(self, watch: Stopwatch, name: str) -> None:
        self.watch, self.name = watch, name

    def __enter__(self) -> None:
        self.t0 = time.perf_counter_ns()

    def __exit__(self, *exc) -> None:
        self.watch.ms[self.name] = (time.perf_counter_ns() - self.t0) / 1e6
