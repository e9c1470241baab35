"""``rangeimage``'s entropy stages side by side: bytes, range error and speed against ``body=zstd``.

    python tools/rangeimage_bodies.py [--pairs 7] [--real PATH/TO/shared/data/real]

On the simulated tunnel's first frame and (with ``--real``) the real KITTI 00 frame 0, every
``body`` at the codec's other defaults: bytes, coverage and range RMSD (the installed range
metric), and encode / decode time as ratios to ``body=zstd`` timed in the same run -- each body
alternates with zstd ``--pairs`` times and the fastest of each is kept, so the ratio holds on a
loaded machine; the load average is printed with the table.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from lwbench import CodecKind, Evaluation, Frame, codec_class, frame_metric, open_dataset

RangeImageCodec = codec_class("rangeimage")
#: Every entropy stage the codec declares (its ``body`` parameter's choices).
BODIES = next(p.choices for p in RangeImageCodec.all_params() if p.name == "body")


def first_frame(dataset: str, **params: object) -> Frame:
    return open_dataset(dataset, params)[0]


def timed(codec, frame: Frame) -> tuple[float, float, bytes]:
    t0 = time.perf_counter()
    data = codec.encode(frame)
    t1 = time.perf_counter()
    RangeImageCodec().use_sensors([frame.sensor]).decode(data)
    return t1 - t0, time.perf_counter() - t1, data


def rows(label: str, frame: Frame, pairs: int) -> list[str]:
    metric = frame_metric("ranges")
    reference = RangeImageCodec(body="zstd")
    out = []
    for body in BODIES:
        codec = RangeImageCodec(body=body)
        timed(codec, frame)  # warm-up (imports, caches)
        best = [float("inf")] * 4
        for _ in range(pairs):
            enc_z, dec_z, ref = timed(reference, frame)
            enc, dec, data = timed(codec, frame)
            best = [min(b, v) for b, v in zip(best, (enc_z, dec_z, enc, dec), strict=True)]
        decoded = RangeImageCodec().use_sensors([frame.sensor]).decode(data)
        m = metric.compute(Evaluation(frame, data, decoded, CodecKind.REPRESENTATION, {}))
        out.append(
            f"| {label} | {body} | {len(data):,} | {len(data) / len(ref):.3f} | {m['coverage']:.4f} "
            f"| {m['range_rmsd'] * 1000:.2f} | {best[2] / best[0]:.2f} | {best[3] / best[1]:.2f} "
            f"| {best[0] * 1000:.0f} / {best[1] * 1000:.0f} |"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=7)
    ap.add_argument("--real", type=Path)
    args = ap.parse_args()
    frames = [("sim tunnel frame 0", first_frame("sim", scene="tunnel", frames=1))]
    if args.real:
        frames.append(("KITTI 00 frame 0", first_frame(str(args.real / "kitti00_frames0-1"))))
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| frame | body | bytes | × zstd bytes | coverage | range RMSD (mm) | encode × zstd | decode × zstd "
          "| zstd encode / decode (ms, context) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, frame in frames:
        for line in rows(label, frame, args.pairs):
            print(line, flush=True)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
