"""How far ``encode_x`` (runtimes as multiples of the reference workload, docs/leaderboard.md)
holds across thread counts and load, against raw milliseconds: the table in that doc.

    python tools/encode_x_stability.py --out /tmp/encx      # ~3 min on 2 cores; needs them idle

The same codecs on the same simulated scans, in process, under four conditions -- 1 thread
(twice: the run-to-run noise), 2 threads, 1 thread beside two busy processes -- each into its
own store with its own machine label; then per codec the spread (largest / smallest over the
conditions) of the mean encode and decode time, in ms and as multiples of the reference.
A development script (not installed): it reproduces a documented figure.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

CODECS = ("raw", "random", "voxel", "draco", "rangeimage")
CONDITIONS = {"1 thread": (1, False), "1 thread again": (1, False), "2 threads": (2, False),
              "1 thread, 2 busy processes": (1, True)}
BURNER = "import numpy as np\nx = np.random.rand(600, 600)\nwhile True:\n    x = x @ x.T / 600.0\n"


def run(out: Path, label: str, threads: int, loaded: bool, frames: int) -> Path:
    store = out / f"{label.replace(' ', '_').replace(',', '')}.sqlite"
    env = {**os.environ, **{v: str(threads) for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                                          "LWBENCH_THREADS")}}
    burners = [subprocess.Popen([sys.executable, "-c", BURNER], env={**env, "OMP_NUM_THREADS": "1",
                                                                      "OPENBLAS_NUM_THREADS": "1"})
               for _ in range(2 if loaded else 0)]
    try:
        words = [w for c in CODECS for w in ("--codec", c)]
        subprocess.run(["lwbench", "run", "--dataset", "sim", "--dataset-param", f"frames={frames}", *words,
                        "--no-sequence-metrics", "--in-process", "--force", "--machine", label, "--store", str(store)],
                       env=env, check=True, stdout=subprocess.DEVNULL)
    finally:
        for b in burners:
            b.kill()
    return store


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=5)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    stores = [run(args.out, label, t, loaded, args.frames) for label, (t, loaded) in CONDITIONS.items()]

    import lwbench

    with lwbench.open_results(*stores) as results:
        board = results.leaderboard(by_machine=True)
        references: dict[str, list[float]] = {}
        for r in results.rows():
            if r["reference_ms"]:
                references.setdefault(r["machine"], []).append(r["reference_ms"])
    values = {(e["codec"], e["machines"][0]): e for e in board}
    print("| codec | figure | " + " | ".join(CONDITIONS) + " | spread (max/min) |")
    print("|---|---|" + "---|" * (len(CONDITIONS) + 1))
    spreads: dict[str, list[float]] = {}
    for codec in CODECS:
        for figure in ("encode_ms", "encode_x", "decode_ms", "decode_x"):
            row = [values[(codec, label)][figure] for label in CONDITIONS]
            spread = max(row) / min(row)
            spreads.setdefault(figure, []).append(spread)
            cells = " | ".join(f"{v:.3g}" for v in row)
            print(f"| {codec} | {figure} | {cells} | {spread:.2f} |")
    print()
    for figure, s in spreads.items():
        print(f"{figure}: median spread {sorted(s)[len(s) // 2]:.2f}, worst {max(s):.2f}")
    print("reference ms per condition: " + ", ".join(f"{label} {sum(v) / len(v):.0f}"
                                                    for label, v in references.items()))


if __name__ == "__main__":
    main()
