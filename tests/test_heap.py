"""The sequence stage hands freed heap memory back between scans (lwbench.run.heap): trims only
when the process grew by the slack since the last trim, so a steady working set costs nothing."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from lwbench.run import heap
from lwbench.run.heap import HeapReturner

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/statm")


def test_it_trims_after_the_process_grew_by_the_slack_and_not_before(monkeypatch):
    calls = []
    returner = HeapReturner(slack_mb=32)
    monkeypatch.setattr(returner, "trim", lambda pad: calls.append(pad))
    returner()
    assert calls == []  # no growth since it was made
    held = np.ones(64 * 2**20 // 8)  # 64 MB touched: resident
    returner()
    assert calls == [0]
    returner()
    assert calls == [0]  # the mark moved to where it trimmed
    del held


def test_without_a_c_library_to_trim_it_does_nothing(monkeypatch):
    monkeypatch.setattr(heap, "malloc_trim", lambda: None)
    returner = HeapReturner(slack_mb=0)
    held = np.ones(2**20)
    returner()  # no error, nothing to call
    assert returner.trim is None
    del held


def _fragment_the_heap(rng: np.random.Generator) -> list[np.ndarray]:
    """What a frame's metrics leave behind: large temporaries (which raise glibc's mmap threshold,
    so later ones come from the heap), then hundreds of mid-sized arrays, a few of them kept --
    the rest is free memory the heap holds between live blocks."""
    for _ in range(2):
        big = np.ones(2**22)
        del big
    blocks = [np.ones(int(rng.integers(2**15, 2**18))) for _ in range(300)]
    return blocks[::7]


@pytest.mark.heavy
def test_peak_mb_is_the_working_set_even_when_earlier_frames_freed_as_much():
    # Issue 33: raw read 0 MiB in a run -- its payload and decoded copy fitted in heap memory the
    # work before had freed (0.00-0.12 MiB here without the trim). The heap's free pages go back
    # before measuring, so the growth is the block's working set.
    from lwbench import get_sensor
    from lwbench.registry import get_registry
    from lwbench.run.evaluate import encode_decode
    from lwbench.run.plan import CodecConfig
    from lwbench.testing import room_scan

    frame = room_scan(get_sensor("os1-128"), seed=0, noise=0.0)
    cls = get_registry().codec("raw")
    scan_mb = frame.points.nbytes / 2**20
    assert scan_mb > 1.0
    rng = np.random.default_rng(0)
    peaks = []
    for _ in range(3):
        live = _fragment_the_heap(rng)
        peaks.append(encode_decode(cls, CodecConfig("raw", {}), cls(), frame).peak_mb)
        del live
    assert all(p is not None and p >= scan_mb for p in peaks), (peaks, scan_mb)
