"""Frames per second of ``lwbench run`` in process, with one isolated worker and with two:
the isolation cost and the scaling figures in docs/hostile.md.

    python tools/scaling.py [--frames 50] [--codecs raw,random,voxel,rangeimage,draco,harris3d] [--repeat 2]

Runs the same command back to back on a fresh store each time (no cache hits), after one
untimed run that fills the simulator's scan cache, and prints wall time, frames/s and the load
average before each run. Read the ratios, not the seconds: the machines are shared.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def run(args: list[str], store: Path) -> float:
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from lwbench.cli import main; main()", "run", *args, "--store", str(store)],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--codecs", default="raw,random,voxel,rangeimage,draco,harris3d")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    base = ["--dataset", "sim", "--dataset-param", "scene=indoor", "--dataset-param", f"frames={a.frames}",
            "--no-sequence-metrics"]
    for c in a.codecs.split(","):
        base += ["--codec", c]
    modes = {"in process": ["--in-process"], "1 worker": ["--workers", "1"], "2 workers": ["--workers", "2"]}
    with tempfile.TemporaryDirectory() as tmp:
        run(base + ["--in-process"], Path(tmp) / "warm.sqlite")  # the simulator's cache
        times: dict[str, list[float]] = {m: [] for m in modes}
        for r in range(a.repeat):
            for mode, extra in modes.items():
                load = os.getloadavg()[0]
                s = run(base + extra, Path(tmp) / f"{mode}-{r}.sqlite".replace(" ", "_"))
                times[mode].append(s)
                print(f"{mode:10s} run {r}: {s:6.1f} s, {a.frames / s:5.2f} frames/s (load before {load:.2f})",
                      flush=True)
    best = {m: min(v) for m, v in times.items()}
    print(f"isolation cost (1 worker / in process): {best['1 worker'] / best['in process']:.2f}x wall")
    print(f"scaling (2 workers / 1 worker, frames/s): {best['1 worker'] / best['2 workers']:.2f}x")


if __name__ == "__main__":
    main()
