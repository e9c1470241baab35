"""Progress of a long command, phase by phase: a live bar on a terminal, plain lines elsewhere.

A run spends minutes in phases that print nothing otherwise -- simulating scans, encoding and
decoding each codec's frames, the sequence metrics (ICP over the whole sequence). Each phase is
a :class:`Phase` of one :class:`Progress`:

- **on a terminal** (stdout and stderr both are one) a rich progress bar per phase, on stderr;
- **elsewhere** (CI logs, ``| tee``, a file) one plain line on stderr when a phase starts, every
  ``interval_s`` seconds while it runs -- also when nothing finished in between, so that a
  phase stuck on one long item still says it is alive and what it is working on -- and when it
  ends::

      lwbench: frames 12/40 (30%) · 1m02s · eta 2m25s · raw 8, gmm 4 · last: gmm frame 5
      lwbench: frames done: 40/40 in 3m10s

The interval is 10 s unless ``LWBENCH_PROGRESS_S`` says otherwise (``0``: a line per update,
which is what the tests use). Lines go to stderr so that stdout stays the command's result (a
table, JSON, CSV) whatever the progress says.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TextIO

__all__ = ["DEFAULT_INTERVAL_S", "Phase", "Progress", "format_duration", "interactive"]

DEFAULT_INTERVAL_S = 10.0


def interactive() -> bool:
    """Whether a live bar can be drawn: a person is watching stdout and stderr (not CI, not a pipe)."""
    return sys.stdout.isatty() and sys.stderr.isatty()


def format_duration(seconds: float) -> str:
    """``42s``, ``3m05s``, ``1h02m``: a duration as a log line says it."""
    s = int(round(max(seconds, 0.0)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


class Phase:
    """One phase's counts. ``update``/``advance`` from the thread doing the work; the plain-line
    heartbeat reads it from its own thread (every field is replaced whole, never half-written)."""

    def __init__(self, owner: Progress, title: str, total: int | None) -> None:
        self.owner, self.title, self.total = owner, title, total
        self.done = 0
        self.what = ""
        self.by_part: Counter[str] = Counter()
        self.started = owner.clock()
        self.last_line = float("-inf")
        self.quiet = False  # not announced yet: the first update prints at once
        self.finished = False
        self._task = None

    def update(self, done: int | None = None, *, total: int | None = None, what: str | None = None,
               part: str | None = None) -> None:
        """``done`` so far (of ``total``); ``what`` says where the work is (``last: gmm frame 5``,
        ``scan 3``); ``part`` (a codec)
        counts one more item finished under that name, so a line can say how far each part is."""
        if total is not None:
            self.total = total
        if done is not None:
            self.done = done
        if what is not None:
            self.what = what
        if part is not None:
            self.by_part[part] += 1
        self.owner._updated(self)

    def advance(self, n: int = 1, *, what: str | None = None, part: str | None = None) -> None:
        self.update(self.done + n, what=what, part=part)

    def line(self) -> str:
        """The plain line of this phase now."""
        elapsed = self.owner.clock() - self.started
        count = f"{self.done}/{self.total}" if self.total else f"{self.done} done"
        bits = [f"{self.title} {count}"]
        if self.total:
            bits[0] += f" ({self.done / self.total:.0%})"
        bits.append(format_duration(elapsed))
        if self.total and 0 < self.done < self.total:
            bits.append(f"eta {format_duration(elapsed / self.done * (self.total - self.done))}")
        if len(self.by_part) > 1:
            bits.append(", ".join(f"{k} {v}" for k, v in self.by_part.items()))
        if self.what and not self.finished:
            bits.append(self.what)
        return "lwbench: " + " · ".join(bits)

    def finish(self) -> None:
        """The phase is over: its last line (plain) or its full bar (terminal)."""
        if self.finished:
            return
        self.finished = True
        if self.total is None or self.done > self.total:
            self.total = self.done
        self.owner._finished(self)

    def __enter__(self) -> Phase:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None and self.total is not None:
            self.done = max(self.done, self.total)  # a phase that ran to its end did all of it
        self.finish()


class Progress:
    """The phases of one command (a context manager; see the module notes).

    ``live`` chooses the bar (default: :func:`interactive`); ``stream`` and ``clock`` are where
    plain lines go and what time is (tests give their own); ``console`` is the rich console the
    bar draws on (default: one on stderr)."""

    def __init__(
        self,
        *,
        live: bool | None = None,
        interval_s: float | None = None,
        stream: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        console=None,
        heartbeat: bool = True,
    ) -> None:
        self.live = interactive() if live is None else live
        if interval_s is None:
            interval_s = float(os.environ.get("LWBENCH_PROGRESS_S", DEFAULT_INTERVAL_S))
        self.interval_s = interval_s
        self.stream = stream
        self.clock = clock
        self.console = console
        self.phases: list[Phase] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._heartbeat = heartbeat and not self.live and interval_s > 0
        self._thread: threading.Thread | None = None
        self._bar = None

    # -- the context -------------------------------------------------------------------------
    def __enter__(self) -> Progress:
        if self.live:
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
            from rich.progress import Progress as Bar

            console = self.console or Console(stderr=True)
            self._bar = Bar(TextColumn("[progress.description]{task.description}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console)
            self._bar.__enter__()
        elif self._heartbeat:
            self._thread = threading.Thread(target=self._beat, name="lwbench-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        for phase in self.phases:
            if exc[0] is None:
                phase.finish()
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._bar is not None:
            self._bar.__exit__(*exc)

    def phase(self, title: str, total: int | None = None, *, announce: bool = True) -> Phase:
        """Start a phase (its first line, or its bar). ``announce=False``: its first line waits for
        its first update or one interval, so that a command refused at once prints only its error."""
        phase = Phase(self, title, total)
        with self._lock:
            self.phases.append(phase)
        if self._bar is not None:
            phase._task = self._bar.add_task(title, total=total)
        elif announce:
            self._print(phase, force=True)
        else:
            phase.last_line = phase.started
            phase.quiet = True
        return phase

    # -- what phases call --------------------------------------------------------------------
    def _updated(self, phase: Phase) -> None:
        if self._bar is not None:
            what = f"{phase.title}: {phase.what}" if phase.what else phase.title
            self._bar.update(phase._task, completed=phase.done, total=phase.total, description=what)
        else:
            self._print(phase)

    def _finished(self, phase: Phase) -> None:
        if self._bar is not None:
            self._bar.update(phase._task, completed=phase.done, total=phase.total, description=phase.title)
            return
        if phase.quiet and not phase.done:  # never announced, nothing done: nothing to say
            return
        elapsed = format_duration(self.clock() - phase.started)
        count = f"{phase.done}/{phase.total}" if phase.total else f"{phase.done}"
        self._write(f"lwbench: {phase.title} done: {count} in {elapsed}")

    def tick(self) -> None:
        """One heartbeat: a line for every running phase whose last line is ``interval_s`` old."""
        with self._lock:
            running = [p for p in self.phases if not p.finished]
        for phase in running:
            self._print(phase, beat=True)

    def _beat(self) -> None:
        while not self._stop.wait(min(self.interval_s, 1.0)):
            self.tick()

    def _print(self, phase: Phase, force: bool = False, beat: bool = False) -> None:
        """A phase's line, if it is due: always when ``force``d, at the first update of a phase not
        announced yet, else once ``interval_s`` has passed since its last line."""
        now = self.clock()
        with self._lock:
            due = force or (phase.quiet and not beat) or now - phase.last_line >= self.interval_s
            if phase.finished or not due:
                return
            phase.last_line, phase.quiet = now, False
        self._write(phase.line())

    def _write(self, text: str) -> None:
        stream = self.stream or sys.stderr
        print(text, file=stream, flush=True)
