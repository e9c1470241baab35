"""Rate-distortion table for the draco, rangeimage and voxel codecs on the real samples.

Stand-in until ``lwbench run`` / ``lwbench leaderboard`` exist: the metrics follow DESIGN.md
(range RMSD / coverage / false returns on the frame's sensor grid; Chamfer = mean of the two
directed mean nearest-neighbour distances). Times are medians of 3 runs after one warm-up call,
on a shared 2-core machine, so compare them as ratios within one table.

    /work/venv/bin/python docs/codecs_rd.py > /tmp/rd.md
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lwbench import Frame
from lwbench.datasets import KittiDataset
from lwbench.registry import get_registry

REAL = Path("/work/shared/data/real")
DATASETS = {
    # Ouster: the loader reads the recording's own beam table from sensor_metadata.json.
    "ouster_os1-128_seq3": {"path": str(REAL / "ouster_os1-128_seq3")},
    # KITTI: the HDL-64E preset (a table derived from one scan without rings is worse).
    "kitti00_frames0-1": {"path": str(REAL / "kitti00_frames0-1"), "sensor": "hdl64e"},
}
CONFIGS: list[tuple[str, dict]] = [
    ("raw", {}),
    *[("draco", {"quantization_bits": b}) for b in (11, 12, 14, 16)],
    *[("rangeimage", {"step": s}) for s in (0.05, 0.02, 0.01)],
    ("rangeimage", {"mode": "lossless"}),
    *[("voxel", {"voxel_size": v}) for v in (1.0, 0.5, 0.2, 0.1)],
    ("voxel", {"voxel_size": 0.2, "encoding": "quantized", "quant_step": 0.01}),
]


def grid_metrics(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    """Range RMSD over cells both clouds hit, coverage of P's cells, share of false returns."""
    p = frame.sensor.project(frame.points).ranges
    q = frame.sensor.project(decoded).ranges
    both = (p > 0) & (q > 0)
    rmsd = float(np.sqrt(np.mean((p[both].astype(np.float64) - q[both]) ** 2))) if both.any() else np.nan
    coverage = both.sum() / max(1, (p > 0).sum())
    false = ((q > 0) & (p <= 0)).sum() / max(1, (q > 0).sum())
    return rmsd, float(coverage), float(false)


def chamfer(a: np.ndarray, b: np.ndarray) -> float:
    return float((cKDTree(a).query(b)[0].mean() + cKDTree(b).query(a)[0].mean()) / 2)


def timed(fn, arg, reps: int = 3) -> tuple[object, float]:
    out = fn(arg)  # warm-up (imports, first allocation)
    ts = []
    for _ in range(reps):
        t = time.perf_counter_ns()
        out = fn(arg)
        ts.append(time.perf_counter_ns() - t)
    return out, float(np.median(ts)) / 1e6


def main() -> None:
    reg = get_registry()
    print("| dataset | codec | params | points in | points out | bytes/frame | ratio | bits/pt "
          "| range RMSD (m) | coverage | false ret. | Chamfer (m) | enc ms | dec ms | ×draco-14 time |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for ds_name, ds_params in DATASETS.items():
        ds = KittiDataset(**ds_params)
        frames = list(ds)
        rows = []
        for codec_name, params in CONFIGS:
            cls = reg.codecs[codec_name]
            vals = []
            for frame in frames:
                data, enc_ms = timed(cls(**params).encode, frame)
                decoded, dec_ms = timed(cls().decode, data)
                rmsd, cov, false = grid_metrics(frame, decoded)
                vals.append((len(frame), len(decoded), len(data), frame.raw_bytes / len(data),
                             8 * len(data) / len(frame), rmsd, cov, false,
                             chamfer(frame.points, decoded), enc_ms, dec_ms))
            rows.append((codec_name, params, np.mean(np.array(vals, dtype=np.float64), axis=0)))
        ref = next(v for c, p, v in rows if c == "draco" and p.get("quantization_bits") == 14)
        for codec_name, params, v in rows:
            ptxt = ", ".join(f"{k}={val}" for k, val in params.items()) or "-"
            print(f"| {ds_name} ({len(frames)} fr.) | {codec_name} | {ptxt} | {v[0]:,.0f} | {v[1]:,.0f} "
                  f"| {v[2]:,.0f} | {v[3]:.1f} | {v[4]:.2f} | {v[5]:.4f} | {v[6]:.3f} | {v[7]:.3f} "
                  f"| {v[8]:.4f} | {v[9]:.1f} | {v[10]:.1f} | {(v[9] + v[10]) / (ref[9] + ref[10]):.2f} |")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
