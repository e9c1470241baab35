"""PocoNet selection time on the real 124,668-point KITTI frame, against iss and sift3d.

The issue's target: <= 0.5 s per ~120k-point scan on this CPU including the k-d tree work (the
paper: 0.046 s on a GTX 1080 Ti). The machine is shared, so the figure that travels is the
ratio to ``iss`` and ``sift3d`` timed in the same process, interleaved run by run; the KNN share
is the part of a selection spent in SciPy's ``cKDTree`` (the pyramid's neighbour, sub-sampling
and up-sampling indices, and carrying the predictions to every point).

    python -m pytest tests/benchmarks/test_bench_poconet.py -m benchmark --benchmark-enable
    python tests/benchmarks/test_bench_poconet.py [RUNS]   # the docs table
"""

from __future__ import annotations

import sys
import time
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from lwbench import Frame, get_sensor
from lwbench.registry import get_registry

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/, when run as a program
from _real import kitti_frame0  # noqa: E402

KITTI = kitti_frame0()
BUDGET = {"points": 10_000}  # PocoNet keeps 8,000-10,000 points per KITTI scan
REFERENCES = ("iss", "sift3d")


@cache
def scan() -> Frame:
    if not KITTI.exists():
        pytest.skip(f"KITTI sample not found at {KITTI}")
    return Frame(np.fromfile(KITTI, np.float32).reshape(-1, 3), get_sensor("hdl64e"), index=0)


def _selector(name: str):
    return get_registry().codec(name)(**BUDGET)


def _time(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def knn_seconds(frame: Frame) -> float:
    """The k-d tree part of one poconet selection, run on its own: the pyramid of the sample the
    network sees, and the nearest-sample query that carries predictions to every point."""
    from lwbench_plugins.poconet.codec import SHIPPED_WEIGHTS, load_checkpoint, trained_points_in
    from lwbench_plugins.poconet.data import prepare
    from scipy.spatial import cKDTree

    net, meta = load_checkpoint(str(SHIPPED_WEIGHTS), "cpu")
    rng = np.random.default_rng([0, frame.index])
    pick = np.sort(rng.choice(len(frame), trained_points_in(meta), replace=False))
    t = time.perf_counter()
    prepare(frame.points[pick], net.config.k, net.config.ratio, len(net.config.d_out), rng)
    cKDTree(frame.points[pick]).query(frame.points, k=1, workers=-1)
    return time.perf_counter() - t


def paired_times(runs: int) -> dict[str, np.ndarray]:
    """``runs`` selection times of poconet and of each reference, interleaved, plus the KNN part."""
    frame = scan()
    sels = {name: _selector(name) for name in ("poconet", *REFERENCES)}
    for sel in sels.values():
        sel.select(frame)  # warm-up (and the checkpoint load)
    times: dict[str, list[float]] = {name: [] for name in (*sels, "knn")}
    for _ in range(runs):
        for name, sel in sels.items():
            times[name].append(_time(lambda sel=sel: sel.select(frame)))
        times["knn"].append(knn_seconds(frame))
    return {k: np.array(v) for k, v in times.items()}


@pytest.mark.benchmark
def test_bench_poconet(benchmark):
    frame, sel = scan(), _selector("poconet")
    idx = benchmark.pedantic(sel.select, args=(frame,), rounds=5, warmup_rounds=1)
    assert len(idx) == BUDGET["points"]
    t = paired_times(3)
    for ref in REFERENCES:
        benchmark.extra_info[f"vs_{ref}"] = float(np.median(t["poconet"] / t[ref]))
    benchmark.extra_info["knn_share"] = float(np.median(t["knn"] / t["poconet"]))


def main(runs: int = 7) -> None:
    frame = scan()
    t = paired_times(runs)
    print(f"KITTI 00 frame 0, {len(frame)} points, budget {BUDGET['points']} points, median of {runs} "
          "interleaved runs")
    print("| selector | median s | poconet / this |")
    print("|---|---|---|")
    for name in ("poconet", *REFERENCES):
        print(f"| {name} | {np.median(t[name]):.3f} | {np.median(t['poconet'] / t[name]):.2f} |")
    print(f"\nKNN (cKDTree) share of a poconet selection: {np.median(t['knn'] / t['poconet']):.0%} "
          f"({np.median(t['knn']):.3f} s)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 7)
