"""How many threads this process may use: the per-worker budget the executors set.

Two worker processes that each start a thread per core on a 2-core machine run slower than
one (``--workers 2`` was 27 % slower than ``--workers 1``: 22.7 s vs 17.9 s). An executor
therefore gives each worker ``cores // workers`` threads, through the environment variables
the numerical libraries read at import (OpenMP, OpenBLAS, MKL: torch and Open3D follow them)
and ``LWBENCH_THREADS``, which lwbench's own parallel calls (SciPy's k-d tree queries) and
plugins read through :func:`thread_budget`.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

__all__ = ["THREADS_ENV", "THREAD_VARS", "thread_budget", "thread_env"]

THREADS_ENV = "LWBENCH_THREADS"
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS", THREADS_ENV)


def thread_budget() -> int:
    """Threads this process may use: ``LWBENCH_THREADS`` when an executor set it, else every
    core (``workers=`` of SciPy's k-d tree queries, and a plugin's own pools, take this)."""
    try:
        return max(1, int(os.environ[THREADS_ENV]))
    except (KeyError, ValueError):
        return os.cpu_count() or 1


@contextlib.contextmanager
def thread_env(threads: int) -> Iterator[None]:
    """The thread variables set to ``threads`` while child processes are started inside the
    block (they read them at import, before any code of ours runs there)."""
    saved = {v: os.environ.get(v) for v in THREAD_VARS}
    os.environ.update({v: str(threads) for v in THREAD_VARS})
    try:
        yield
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old
