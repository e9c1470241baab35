"""Sensor models derived from scans with no ring field and no usable order, before and after issue 25.

    python tools/sensor_guesses.py make DIR [--real PATH/TO/shared/data/real]   # writes the scans
    python tools/sensor_guesses.py derive DIR > after.jsonl                      # this checkout
    PYTHONPATH=/path/to/old/checkout python tools/sensor_guesses.py derive DIR > before.jsonl
    python tools/sensor_guesses.py table before.jsonl after.jsonl                # Markdown

The scans are written once (``make``, with this checkout's generators) so that both versions of
``derive_sensor`` see the same points: generated scans of each kind the issue
names (HDL-64E keyframes, OS1-64 raw and deskewed, a short-range PandarQT, a rotating 2-D laser,
a sensor no preset describes) and the real samples, each shuffled and voxel-downsampled.
``derive`` uses only what both versions have (``derive_sensor(points, warn=False)``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def make(out: Path, real: Path | None) -> None:
    from _scans import rotating_2d_laser_scan, shuffled, street_scan, tilted, voxel_downsampled

    from lwbench import SensorModel, get_sensor
    from lwbench.io import read_kitti_bin, read_point_file

    out.mkdir(parents=True, exist_ok=True)
    hdl64 = SensorModel("hdl64e-10hz", get_sensor("hdl64e").elevations_deg, 360 / 2083, 0.9, 120.0, 10.0)
    kitti_like = street_scan(hdl64, laser_height_m=0.2, table_jitter_deg=0.1)
    os1 = street_scan(
        get_sensor("os1-64"),
        table_jitter_deg=0.05,
        laser_height_m=0.03,
        azimuth_offsets_deg=np.tile([3.0, 1.0, -1.0, -3.0], 16),
    )
    qt = street_scan(get_sensor("pandarqt"), height=0.5)
    forty = street_scan(SensorModel("forty", tuple(np.linspace(-20, 20, 40)), 0.2, 0.5, 100.0, 10.0))
    scans = {
        "gen HDL-64E (KITTI-like) shuffled [64]": shuffled(kitti_like),
        "gen HDL-64E voxel 0.2 m shuffled [64]": shuffled(voxel_downsampled(kitti_like, 0.2)),
        "gen OS1-64 shuffled [64]": shuffled(os1),
        "gen OS1-64 deskewed (0.2 deg tilt) [64]": shuffled(tilted(os1, 0.2)),
        "gen OS1-64 tilted 0.3 deg, voxel 0.2 m [64]": shuffled(voxel_downsampled(tilted(os1, 0.3), 0.2)),
        "gen PandarQT shuffled [64]": shuffled(qt),
        "gen PandarQT voxel 0.1 m [64]": shuffled(voxel_downsampled(qt, 0.1)),
        "gen rotating 2-D laser [-]": rotating_2d_laser_scan(),
        "gen 40-beam, no preset [40]": shuffled(forty),
    }
    if real is not None and real.is_dir():
        samples = {
            "real KITTI 00 frame 0 (HDL-64E) [64]": read_kitti_bin(real / "kitti00_frames0-1" / "000000.bin").points,
            "real OS1-128 [128]": read_kitti_bin(real / "ouster_os1-128_seq3" / "000000.bin").points,
            "real HDL-32 pair source [32]": read_point_file(real / "hdl32_pair" / "source.pcd").points,
            "real 64-beam PCD, no ring (Pandar64) [64]": read_point_file(
                real / "lidar64_static_pcd" / "2021-10-26-16-21-29-468.pcd"
            ).points,
            "real KITTI object (camera crop) [46 in view]": read_kitti_bin(
                real / "kitti_object_000008" / "000008.bin"
            ).points,
        }
        for name, pts in samples.items():
            scans[name.replace(" [", " shuffled [")] = shuffled(pts)
            scans[name.replace(" [", " voxel 0.2 m [")] = shuffled(voxel_downsampled(pts, 0.2))
    for i, pts in enumerate(scans.values()):
        np.save(out / f"{i:02d}.npy", pts.astype(np.float32))
    (out / "names.json").write_text(json.dumps(list(scans), indent=1))


def derive(folder: Path) -> None:
    import warnings

    try:
        from lwbench import derive_sensor  # public since issue 34
    except ImportError:  # an older checkout (the "before" of issue 25)
        from lwbench.derive import derive_sensor

    names = json.loads((folder / "names.json").read_text())
    for i, name in enumerate(names):
        pts = np.load(folder / f"{i:02d}.npy")
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                d = derive_sensor(pts, warn=False)
            except ValueError as exc:
                print(json.dumps({"case": name, "error": str(exc)[:80]}))
                continue
        row = {
            "case": name,
            "points": len(pts),
            "method": d.method,
            "beams": d.sensor.n_beams,
            "step": round(d.sensor.azimuth_step_deg, 4),
            "rays": d.sensor.n_rays,
            "seconds": round(time.perf_counter() - t0, 2),
            "rule": getattr(d, "rule", ""),
        }
        print(json.dumps(row))


def table(before: Path, after: Path) -> None:
    b = {r["case"]: r for r in map(json.loads, before.read_text().splitlines())}
    a = {r["case"]: r for r in map(json.loads, after.read_text().splitlines())}

    def cell(r: dict) -> str:
        if "error" in r:
            return f"error: {r['error']}"
        return f"{r['beams']} beams, {r['step']:.3f} deg ({r['method']})"

    print("| scan [true beams] | points | before | after | after: rule |")
    print("|---|---|---|---|---|")
    for case in a:
        rule = a[case].get("rule", "").split(":")[0]
        print(
            f"| {case} | {a[case].get('points', '')} | {cell(b[case]) if case in b else '-'} | {cell(a[case])} | "
            f"{rule} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make")
    m.add_argument("dir", type=Path)
    m.add_argument("--real", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data" / "real")
    d = sub.add_parser("derive")
    d.add_argument("dir", type=Path)
    t = sub.add_parser("table")
    t.add_argument("before", type=Path)
    t.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.cmd == "make":
        make(args.dir, args.real)
    elif args.cmd == "derive":
        derive(args.dir)
    else:
        table(args.before, args.after)


if __name__ == "__main__":
    main()
