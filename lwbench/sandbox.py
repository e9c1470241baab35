"""One child process under limits -- what the run's workers and the fuzzer's decode server share.

Other people's code (a plugin's encoder, a decoder fed crafted bytes) runs in a child so that
whatever it does costs one answer, not the parent:

- the child is **spawned** (forking after torch has started its thread pool can hang torch
  calls in the child) with a chosen number of threads for every numerical library;
- it **dies with its parent**, however the parent ends (``PR_SET_PDEATHSIG`` and a watchdog);
- it writes **no core dumps** (a crash is reported, not dumped);
- its **memory is capped** (``RLIMIT_DATA`` at what it holds once started plus a ceiling): a
  memory bomb fails with ``MemoryError`` inside the child instead of taking the machine;
- a child that does not answer in time is **killed**, and :func:`how_it_died` says how a dead one
  ended (a segfault, an abort, a kill).

:class:`Sandbox` is the parent's handle: start (and wait for the child's ``ready``), send, wait
for an answer with a deadline, kill, stop. The child's entry point is a module-level function
``target(conn, *args)`` that calls :func:`enter_child` first, imports what it needs, calls
:func:`cap_memory`, then sends ``("ready", ...)`` and serves messages.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable
from multiprocessing import get_context
from typing import Any

from lwbench.errors import LwbenchError
from lwbench.parallel import thread_env

__all__ = ["Sandbox", "SandboxError", "cap_memory", "enter_child", "how_it_died", "reset_peak", "status_mb"]


class SandboxError(LwbenchError):
    """A child process did not start (it died while starting, or did not say it was ready)."""


# -- in the child ---------------------------------------------------------------------------------
def status_mb(key: str) -> float:
    """A ``/proc/self/status`` field in MB (``VmData``, ``VmRSS``, ``VmHWM``); 0 where there is none."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0.0


def reset_peak() -> None:
    """Reset ``VmHWM`` (the peak resident size) to the current size, so a peak is per task."""
    with contextlib.suppress(OSError):
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")


def _die_with_parent(parent: int) -> None:
    with contextlib.suppress(Exception):  # Linux only; the watchdog below covers the rest
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(0.5)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="lwbench-parent-watch", daemon=True).start()


def enter_child(parent: int) -> None:
    """First thing a child does: end with ``parent`` (however it ends) and dump no core."""
    import resource

    _die_with_parent(parent)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def cap_memory(ceiling_mb: float | None) -> None:
    """Cap the child's data segment at what it holds now plus ``ceiling_mb`` (after its imports,
    so that the ceiling is what one task may take); no cap for ``None`` / 0."""
    import resource

    data = status_mb("VmData")
    if ceiling_mb and data:
        with contextlib.suppress(ValueError, OSError):
            hard = resource.getrlimit(resource.RLIMIT_DATA)[1]
            resource.setrlimit(resource.RLIMIT_DATA, (int((data + ceiling_mb) * 2**20), hard))


# -- in the parent --------------------------------------------------------------------------------
def how_it_died(code: int | None) -> str:
    """A dead child's exit code in words (``was killed by SIGSEGV (a segmentation fault)``)."""
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = {"SIGSEGV": " (a segmentation fault)", "SIGABRT": " (native code aborted: out of memory?)",
                "SIGKILL": " (killed: out of memory?)"}.get(name, "")
        return f"was killed by {name}{hint}"
    return f"exited with status {code}"


class Sandbox:
    """The parent's handle on one child running ``target(conn, parent_pid, *args)``."""

    def __init__(self, target: Callable[..., None], args: tuple = (), *, name: str = "lwbench-child",
                 threads: int | None = None) -> None:
        self.target, self.args, self.name, self.threads = target, tuple(args), name, threads
        self.proc: Any = None
        self.conn: Any = None

    def start(self, timeout_s: float, what: str = "a child process") -> Any:
        """Spawn the child and wait for its ``("ready", ...)``; returns that message."""
        self.spawn()
        return self.wait_ready(timeout_s, what)

    def spawn(self) -> None:
        """Start the child without waiting (start several, then :meth:`wait_ready` on each)."""
        ctx = get_context("spawn")
        parent, child = ctx.Pipe()
        self.proc = ctx.Process(target=self.target, args=(child, os.getpid(), *self.args), daemon=True,
                                name=self.name)
        with thread_env(self.threads) if self.threads else contextlib.nullcontext():
            self.proc.start()
        child.close()
        self.conn = parent

    def wait_ready(self, timeout_s: float, what: str = "a child process") -> Any:
        """The child's first message (its ``ready``), or :class:`SandboxError` (killed if it hangs)."""
        try:
            if not self.conn.poll(timeout_s):
                self.kill()
                raise SandboxError(f"{what} did not start within {timeout_s:g} s")
            return self.conn.recv()
        except (EOFError, OSError):
            self.proc.join(5)
            raise SandboxError(f"{what} died while starting ({how_it_died(self.proc.exitcode)})") from None

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.is_alive()

    @property
    def sentinel(self):
        return self.proc.sentinel

    @property
    def exitcode(self) -> int | None:
        return None if self.proc is None else self.proc.exitcode

    def send(self, message: Any) -> None:
        self.conn.send(message)

    def poll(self, timeout: float = 0.0) -> bool:
        return self.conn.poll(timeout)

    def recv(self) -> Any:
        return self.conn.recv()

    def call(self, message: Any, timeout_s: float) -> Any:
        """Send ``message`` and wait for the answer: the answer, ``"timeout"`` or ``"died"``."""
        try:
            self.conn.send(message)
            if not self.conn.poll(timeout_s):
                return "timeout"
            return self.conn.recv()
        except (EOFError, OSError):
            return "died"

    def kill(self) -> int | None:
        """Kill the child (if it still runs) and reap it; returns its exit code."""
        if self.proc is None:
            return None
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        return self.proc.exitcode

    def stop(self, *, kill: bool = False) -> None:
        """End the child: politely (``None`` on the pipe: it returns) unless ``kill``, then killed
        if it is still there after 5 s."""
        if self.proc is None:
            return
        if self.proc.is_alive() and not kill:
            with contextlib.suppress(OSError, BrokenPipeError):
                self.conn.send(None)
            self.proc.join(5)
        self.kill()
        with contextlib.suppress(OSError):
            self.conn.close()
