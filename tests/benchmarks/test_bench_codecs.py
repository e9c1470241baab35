"""Encode + decode time per ~120k-point scan for draco, rangeimage, voxel, laz and cloudini.

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
from lwbench_plugins.cloudini import CloudiniCodec
from lwbench_plugins.draco import DracoCodec
from lwbench_plugins.laz import LazCodec
from lwbench_plugins.rangeimage import RangeImageCodec
from lwbench_plugins.voxel import VoxelSelector

from lwbench import Codec, Frame, Payload, get_sensor

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
    "laz-1mm": (LazCodec, {}),
    "laz-1cm": (LazCodec, {"scale": 0.01}),
    "cloudini-1mm": (CloudiniCodec, {}),
    "cloudini-1cm": (CloudiniCodec, {"resolution": 0.01}),
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


@pytest.mark.benchmark
@pytest.mark.parametrize("resolution", [0.001, 0.01])
def test_cloudini_against_pureini_and_draco(benchmark, resolution: float) -> None:
    """lwbench's Cloudini (numpy + zstandard) against pureini (Rust; GPL-3.0, the tests' oracle)
    writing and reading the same bytes, and against Draco-14: the three round trips interleaved,
    a warm-up and 7 timed rounds, fastest of each; ``vs_pureini`` and ``vs_draco`` are the ratios."""
    pureini = pytest.importorskip("pureini")
    frame = scan()
    info = pureini.EncodingInfo(
        fields=[pureini.PointField(f, 4 * i, pureini.FieldType.FLOAT32, resolution) for i, f in enumerate("xyz")],
        width=len(frame),
        height=1,
        point_step=12,
        encoding_opt=pureini.EncodingOptions.LOSSY,
        compression_opt=pureini.CompressionOption.ZSTD,
    )
    raw = np.ascontiguousarray(frame.points, np.float32).tobytes()
    codec, draco = CloudiniCodec(resolution=resolution, intensity=False), DracoCodec(quantization_bits=14)
    assert Payload.from_bytes(codec.encode(frame)).body == pureini.PointcloudEncoder(info).encode(raw)

    def theirs() -> bytes:
        return pureini.PointcloudDecoder().decode(pureini.PointcloudEncoder(info).encode(raw))[0]

    runs = {"lwbench": lambda: round_trip(codec, frame), "pureini": theirs, "draco": lambda: round_trip(draco, frame)}
    times: dict[str, list[float]] = {name: [] for name in runs}
    for i in range(8):
        for name, run in runs.items():
            t = time.perf_counter()
            run()
            if i:  # round 0 warms up
                times[name].append(time.perf_counter() - t)
    best = {name: min(t) * 1e3 for name, t in times.items()}
    benchmark.pedantic(round_trip, args=(codec, frame), rounds=7, warmup_rounds=1)
    benchmark.extra_info.update(
        {
            "points": len(frame),
            **{f"{name}_ms": round(ms, 2) for name, ms in best.items()},
            "vs_pureini": round(best["lwbench"] / best["pureini"], 2),
            "vs_draco": round(best["lwbench"] / best["draco"], 3),
        }
    )
