"""A fixed reference workload, timed on the machine (and in the process) that evaluates codecs,
so that runtimes travel between machines as multiples of it (``encode_x`` on a board).

A codec's milliseconds say as much about the CPU and its load as about the codec. Each worker
times one fixed workload between its evaluations (every :data:`REFRESH_S` seconds) -- the same
process, the same neighbours -- and every row it writes carries that time
(``extra["reference_ms"]``); a board divides the runtime ids by it. The workload is issue 19's:
a 57,600 x 500 float64 rational-quadratic kernel, ``|x|^2 + |z|^2 - 2 X Z^T`` in numpy -- a
dense BLAS product and memory-bound elementwise work, the mix most codecs here spend their time
on. How far the normalisation holds (threads, load) is measured in docs/leaderboard.md.
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["REFERENCE_WORKLOAD", "reference_ms", "time_reference"]

#: What :func:`reference_ms` times (part of every row that carries a reference time).
REFERENCE_WORKLOAD = "rq-kernel-57600x500-float64"


def time_reference(repeats: int = 3) -> float:
    """Median wall time (ms) of the reference workload on one thread, ``repeats`` runs after one
    warm-up. One thread whatever the process's budget: the reference measures a core's speed
    under its load, so that a codec that uses more threads shows it (its ``encode_x`` drops) and
    one that does not keeps its figure when the budget changes (measured in docs/leaderboard.md:
    with the budget's threads the reference ran 20 % faster at 2 threads and every single-threaded
    codec's figure rose by as much)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        return _time_workload(repeats)


#: Rows of the kernel computed at once: the workload runs in ~30 MB pieces, so that timing it
#: never costs a worker under a memory ceiling its evaluations (the whole 57,600 x 500 kernel and
#: its temporaries took ~700 MB, over a 400 MB ceiling: tests/test_faults.py).
CHUNK_ROWS = 7_200


def _time_workload(repeats: int) -> float:
    rng = np.random.default_rng(0)
    x, z = rng.uniform(size=(57_600, 3)), rng.uniform(size=(500, 3))
    x2, z2 = (x * x).sum(1)[:, None], (z * z).sum(1)[None, :]
    times = []
    for i in range(repeats + 1):
        t = time.perf_counter()
        for start in range(0, len(x), CHUNK_ROWS):
            rows = slice(start, start + CHUNK_ROWS)
            d2 = x2[rows] + z2 - 2.0 * (x[rows] @ z.T)
            k = 10.0 * (1.0 + d2 / 2.0) ** -1.0
            del k, d2
        if i:  # the first run pays for page faults and BLAS start-up
            times.append(time.perf_counter() - t)
    return 1000.0 * float(np.median(times))


#: Seconds a reference time is reused before it is measured again: the load on a shared machine
#: changes over a long run, so the reference is re-timed between evaluations (about 1 s in 30:
#: 3 % of a run) rather than once at a worker's start.
REFRESH_S = 30.0
_last: list[float] = []  # [measured at (monotonic s), ms]


def reference_ms() -> float:
    """This process's reference time (ms): measured now if the last measurement is older than
    :data:`REFRESH_S`, so that it reflects the load the evaluations around it ran under."""
    now = time.monotonic()
    if not _last or now - _last[0] > REFRESH_S:
        _last[:] = [now, time_reference()]
        _last[0] = time.monotonic()
    return _last[1]
