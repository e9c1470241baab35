"""Encode + decode time per ~120k-point scan for draco, rangeimage and voxel.

Draco (14 bits, level 7) is the reference: each benchmark times its codec and Draco in
alternation and stores the ratio of their fastest round trips in ``extra_info["vs_draco"]``.
Minimums and interleaving, because on a shared machine the noise only ever adds time and
drifts; the ratio is the figure to compare, the absolute time only its context.

    python -m pytest tests/benchmarks/test_bench_codecs.py -m benchmark --benchmark-enable
"""

from __future__ import annotations

import time
from functools import cache

import numpy as np
import pytest
from _real import kitti_frame0
from lwbench_plugins.draco import DracoCodec
from lwbench_plugins.rangeimage import RangeImageCodec
from lwbench_plugins.voxel import VoxelSelector

from lwbench import Codec, Frame, get_sensor

KITTI = kitti_frame0()

CODECS: dict[str, tuple[type[Codec], dict]] = {
    "draco-14": (DracoCodec, {"quantization_bits": 14}),
    "draco-11": (DracoCodec, {"quantization_bits": 11}),
    "rangeimage-1cm": (RangeImageCodec, {"step": 0.01}),
    "rangeimage-1cm-zstd": (RangeImageCodec, {"step": 0.01, "body": "zstd"}),
    "rangeimage-1cm-norefine": (RangeImageCodec, {"step": 0.01, "refine": "none"}),
    "rangeimage-5cm": (RangeImageCodec, {"step": 0.05}),
    "rangeimage-lossless": (RangeImageCodec, {"mode": "lossless"}),
    "voxel-0.2": (VoxelSelector, {"voxel_size": 0.2}),
    "voxel-0.5": (VoxelSelector, {"voxel_size": 0.5}),
}


@cache
def scan() -> Frame:
    """KITTI 00 frame 0 (124,668 points) when the sample is there, else a 120k-point
    synthetic HDL-64E sweep of the same size."""
    sensor = get_sensor("hdl64e")
    if KITTI.exists():
        return Frame(np.fromfile(KITTI, dtype=np.float32).reshape(-1, 3), sensor)
    rng = np.random.default_rng(0)
    ranges = 5 + 30 * rng.random(sensor.shape)
    ranges[rng.random(sensor.shape) < 0.08] = 0
    return Frame(sensor.unproject(ranges), sensor)


def round_trip(codec: Codec, frame: Frame) -> np.ndarray:
    return type(codec)().decode(codec.encode(frame))


def paired_ratio(codec: Codec, frame: Frame, pairs: int = 7) -> tuple[float, float]:
    """(codec ms, Draco-14 ms): fastest of ``pairs`` round trips each, the two interleaved so
    that load changes on the shared machine hit both alike."""
    draco = DracoCodec(quantization_bits=14)
    round_trip(draco, frame)
    round_trip(codec, frame)
    mine, ref = [], []
    for _ in range(pairs):
        t = time.perf_counter()
        round_trip(codec, frame)
        mine.append(time.perf_counter() - t)
        t = time.perf_counter()
        round_trip(draco, frame)
        ref.append(time.perf_counter() - t)
    return min(mine) * 1e3, min(ref) * 1e3


@pytest.mark.benchmark
@pytest.mark.parametrize("name", list(CODECS))
def test_encode_decode_time(benchmark, name: str) -> None:
    cls, params = CODECS[name]
    codec, frame = cls(**params), scan()
    decoded = benchmark.pedantic(round_trip, args=(codec, frame), rounds=7, warmup_rounds=1)
    assert decoded.ndim == 2 and decoded.shape[1] == 3 and 0 < len(decoded) <= len(frame)
    mine, ref = paired_ratio(codec, frame)
    benchmark.extra_info.update(
        {"points": len(frame), "bytes": len(codec.encode(frame)), "paired_ms": round(mine, 2),
         "draco_ms": round(ref, 2), "vs_draco": round(mine / ref, 3)}
    )
