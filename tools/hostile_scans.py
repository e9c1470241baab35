"""Every codec x hostile scan, through the evaluator in an isolated worker: the table in
docs/hostile.md.

    python tools/hostile_scans.py [--big N] [--timeout S] [CODEC ...]

Inputs: empty, 1 and 3 points, 1,000 identical points, 1,000 points at the origin, returns
beyond the sensor's max range, a float64 scan, and (with ``--big``, default 10 M) a huge scan.
NaN/inf rows and ``(N, 2)`` arrays never reach a codec (``Frame`` refuses them, loaders drop
non-returns), so they are one line of the table. Each cell: ``ok`` (with the decoded point
count), or the failure row's error; a timeout or a dead worker would show as WorkerError.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lwbench import Frame, get_sensor
from lwbench.registry import get_registry
from lwbench.run.evaluate import Evaluator
from lwbench.run.plan import expand_codec_configs
from lwbench.testing import room_scan


def inputs(big: int) -> dict[str, Frame]:
    s = get_sensor("vlp16")
    room = room_scan(s, seed=2)
    rng = np.random.default_rng(0)
    far = room.points * (2.5 * s.max_range / np.linalg.norm(room.points, axis=1, keepdims=True))
    out = {
        "empty": Frame(np.zeros((0, 3), np.float32), s),
        "1 point": Frame(room.points[:1], s),
        "3 points": Frame(room.points[:3], s),
        "1,000 identical": Frame(np.repeat(room.points[:1], 1000, axis=0), s),
        "1,000 at the origin": Frame(np.zeros((1000, 3), np.float32), s),
        "beyond max range": Frame(far.astype(np.float32), s),
        "float64 scan": Frame(room.points.astype(np.float64), s),
    }
    if big:
        pts = rng.uniform(-9, 9, (big, 3)).astype(np.float32)
        out[f"{big / 1e6:g} M points"] = Frame(pts, s)
    return out


def cell(result) -> str:
    if result.status == "ok":
        return f"ok ({int(result.metrics.get('points_out') or 0):,} pts)"
    return result.error.split("\n")[0][:110].replace("|", "/")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("codecs", nargs="*")
    ap.add_argument("--big", type=int, default=10_000_000)
    args = ap.parse_args()
    reg = get_registry()
    names = args.codecs or sorted(n for n in reg.codecs if not n.startswith("test-"))
    frames = inputs(args.big)
    ev = Evaluator(reg)
    print("| input | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for label, frame in frames.items():
        cells = []
        for name in names:
            cls = reg.codec(name)
            (config,) = expand_codec_configs(cls, {k: [v] for k, v in cls.test_params().items()}, 0)
            t = time.perf_counter()
            (result,) = ev.evaluate(frame, [config])
            cells.append(f"{cell(result)}, {time.perf_counter() - t:.1f} s")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
