"""The range metrics before and after they moved from cells to directions (issue 11, docs/metrics.md).

    python tools/range_metrics_before_after.py [--real PATH/TO/shared/data/real]

"cells" is the old definition (both clouds projected onto the sensor's range image, nearest
return per cell, compared cell by cell); "directions" is ``lwbench_metrics.ranges`` (each
original return paired with the nearest decoded return within half a beam/azimuth spacing).
Case 1 rotates a scan *and* its decoded cloud together by half an azimuth step -- no codec can
make that matter, so a metric that moves measures the grid. Case 2 scores codecs on real scans.
Prints Markdown.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from lwbench_metrics.ranges import RangeMetric

from lwbench import CodecKind, Evaluation, Frame
from lwbench.registry import get_registry
from lwbench.run import resolve_dataset


def cells(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    """The old cell-based (range_rmsd, coverage, false_returns)."""
    s = frame.sensor
    a, b = s.project(frame.points).ranges, s.project(decoded).ranges
    both = (a > 0) & (b > 0)
    rmsd = float(np.sqrt(np.mean((a[both].astype(np.float64) - b[both]) ** 2))) if both.any() else math.nan
    return rmsd, both.sum() / max(1, (a > 0).sum()), ((b > 0) & ~(a > 0)).sum() / max(1, (b > 0).sum())


def directions(frame: Frame, decoded: np.ndarray) -> tuple[float, float, float]:
    m = RangeMetric().compute(Evaluation(frame, b"", decoded, CodecKind.REPRESENTATION, {}))
    rmsd = m["range_rmsd"] if m["range_rmsd"] is not None else math.nan
    return rmsd, m["coverage"] or 0.0, m["false_returns"] or 0.0


def rotate_z(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return (np.asarray(points, np.float64) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T).astype(np.float32)


def decode(codec: str, frame: Frame) -> np.ndarray:
    cls = get_registry().codec(codec)
    data = cls().encode(frame)
    return cls().use_sensors([frame.sensor]).decode(data)


def fmt(v: tuple[float, float, float]) -> str:
    return f"{100 * v[0]:.2f} cm / {v[1]:.3f} / {v[2]:.3f}"


def rotation_case(frame: Frame, codecs: list[str], label: str) -> None:
    print(f"\n**{label}**, {len(frame):,} points; rotated together by half an azimuth step "
          "(range RMSD / coverage / false returns)\n")
    print("| codec | cells, as is | cells, rotated | directions, as is | directions, rotated |")
    print("|---|---|---|---|---|")
    half = 0.5 * frame.sensor.azimuth_step_rad
    for codec in codecs:
        q = decode(codec, frame)
        turned = Frame(rotate_z(frame.points, half), frame.sensor)
        qt = rotate_z(q, half)
        print(f"| {codec} | {fmt(cells(frame, q))} | {fmt(cells(turned, qt))} | "
              f"{fmt(directions(frame, q))} | {fmt(directions(turned, qt))} |")


def real_case(real: Path, codecs: list[str]) -> None:
    reg = get_registry()
    print("\n**Real scans**, frame 0 of each folder, sensor as the loader derives it "
          "(range RMSD / coverage / false returns)\n")
    print("| folder | codec | points out / in | cells | directions |")
    print("|---|---|---|---|---|")
    for folder in sorted(p for p in real.iterdir() if p.is_dir()):
        frame = resolve_dataset(reg, str(folder), {}, 0).build(reg)[0]
        for codec in codecs:
            q = decode(codec, frame)
            print(f"| {folder.name} | {codec} | {len(q):,} / {len(frame):,} | {fmt(cells(frame, q))} | "
                  f"{fmt(directions(frame, q))} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, help="the folder of real samples (shared/data/real)")
    args = ap.parse_args()
    reg = get_registry()
    tunnel = resolve_dataset(reg, "sim", {"scene": "tunnel", "frames": 1}, 0).build(reg)[0]
    rotation_case(tunnel, ["vsgp", "draco", "rangeimage", "random"], "Simulated VLP-16 tunnel (10 m), frame 0")
    from lwbench.testing import room_scan

    room = room_scan(reg.dataset("sim")(scene="tunnel").sensor, seed=0)
    rotation_case(room, ["vsgp", "draco", "rangeimage", "random"], "Off-grid VLP-16 room (lwbench.testing)")
    if args.real:
        real_case(args.real, ["random", "rangeimage", "draco", "vsgp"])


if __name__ == "__main__":
    main()
