"""How far ``rangeimage`` puts each return from where it was, and what the offsets cost.

Every return is decoded (version 4 keeps them all), on its cell's anchored ray moved by its
quantized azimuth / elevation offset: with ``offset_step=s`` (in grid spacings) a direction is
within ``s / 2`` spacings of the original's along each axis; ``lossless_directions`` leaves only
float32 rounding. This prints, per shared real folder (first frame, the loader's sensor model),
the 3-D distance of each decoded return from its own original -- paired exactly through the
encoder's ``Layers.source``, with ``mode=lossless`` so that only the direction moves it -- and the
payload bytes at the default 1 cm step. The rate-distortion tables themselves come from
``examples/runs/codecs_rd.toml`` (``lwbench run --config`` + ``lwbench leaderboard``).

    python tools/codecs_rd.py PATH/TO/shared/data/real
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lwbench import codec_class, open_dataset

SETTINGS = (
    ("offset_step=1 (the cell's ray)", {"offset_step": 1.0}),
    ("offset_step=0.5", {"offset_step": 0.5}),
    ("offset_step=0.25 (default)", {}),
    ("offset_step=0.0625", {"offset_step": 0.0625}),
    ("lossless_directions", {"lossless_directions": True}),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("real", type=Path, help="the shared real samples (one dataset folder each)")
    real = ap.parse_args().real
    RangeImageCodec = codec_class("rangeimage")  # noqa: N806 - the class, named as the plugin names it
    print("| folder | offsets | returns decoded | off-position mean (mm) | p95 (mm) | max (mm) | bytes (1 cm step) |")
    print("|---|---|---|---|---|---|---|")
    for folder in sorted(p for p in real.iterdir() if p.is_dir()):
        frame = open_dataset(folder)[0]
        for label, params in SETTINGS:
            exact = RangeImageCodec(mode="lossless", **params)
            _, layers, _ = exact.layers(frame)
            decoded = RangeImageCodec().use_sensors([frame.sensor]).decode(exact.encode(frame))
            gap = np.linalg.norm(decoded.astype(np.float64) - frame.points[layers.source], axis=1) * 1000
            size = len(RangeImageCodec(**params).encode(frame))
            print(f"| {folder.name} | {label} | {len(decoded):,} of {len(frame):,} | {gap.mean():.2f} "
                  f"| {np.percentile(gap, 95):.2f} | {gap.max():.2f} | {size:,} |", flush=True)


if __name__ == "__main__":
    main()
