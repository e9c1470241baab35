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
    monkeypatch.setattr(heap, "_malloc_trim", lambda: None)
    returner = HeapReturner(slack_mb=0)
    held = np.ones(2**20)
    returner()  # no error, nothing to call
    assert returner.trim is None
    del held
