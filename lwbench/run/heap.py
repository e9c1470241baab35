"""Freed heap memory handed back to the system during a sequence task.

A sequence task churns tile-sized arrays for thousands of scans. glibc keeps what numpy frees
in its heap (after the first large free it raises its mmap threshold, so later large arrays come
from the heap too), and that free memory fragments: tracking 200 town scans grew a worker from
211 to 441 MB, with the same values. Two ways out were measured on 120 town scans (map,
tracking and occupancy, one process):

| glibc setting | localization | occupancy | RSS at the scan boundaries, peak |
|---|---|---|---|
| default | 68.9 s | 45.3 s | 392 MB |
| mmap threshold fixed at 128 kB (every large array a fresh mmap) | 99.7 s | 89.3 s | 280 MB |
| ``malloc_trim(0)`` after every scan | 75.8 s | 55.4 s | 274 MB |

A fixed threshold zero-fills fresh pages for every temporary (a quarter of the run's CPU time
was the kernel's); trimming returns the free pages once and keeps the heap's reuse. So a
:class:`HeapReturner` trims when the process has grown by ``slack_mb`` since it last did --
rarely on a steady working set -- and is a no-op off glibc.
"""

from __future__ import annotations

import os

from lwbench.measure import malloc_trim

__all__ = ["HeapReturner"]

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def _rss_bytes() -> int | None:
    try:
        with open("/proc/self/statm", "rb") as fh:
            return int(fh.read().split()[1]) * _PAGE
    except (OSError, ValueError, IndexError):
        return None


class HeapReturner:
    """Call it between scans: trims the heap when resident memory grew by ``slack_mb`` since the
    last trim (reading ``/proc/self/statm`` costs microseconds; a trim, milliseconds)."""

    def __init__(self, slack_mb: float = 64.0) -> None:
        self.trim = malloc_trim()
        self.slack = int(slack_mb * 2**20)
        self.mark = _rss_bytes() if self.trim is not None else None

    def __call__(self) -> None:
        if self.trim is None or self.mark is None:
            return
        rss = _rss_bytes()
        if rss is None or rss <= self.mark + self.slack:
            return
        self.trim(0)
        self.mark = _rss_bytes() or rss
