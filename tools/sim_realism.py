"""Realism check: simulated scans against a real one, printed as Markdown (for ``docs/sim.md``).

    python tools/sim_realism.py --real PATH/TO/shared/data/real [--every N]

Urban (HDL-64E) is compared with a real KITTI HDL-64E scan: points per scan, range deciles and
the share of ground points, defined the same way for both as points less than 0.25 m above the
ground plane under the sensor, i.e. ``z < -(1.73 - 0.25) m`` in the sensor frame (KITTI's
Velodyne is mounted 1.73 m above the road; the simulated car uses the same height). The
tunnel's points per scan are compared with the VSGP paper's "around 10K to 50K points" per
observation. Intensities are compared with the one real HDL-64E scan that has them (KITTI
object 000008, cropped to the camera's view). Last, ICP (Open3D point-to-plane, 0.25 m voxels,
identity start) between consecutive urban scans against the true relative motion (1 m per scan
at 10 m/s).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lwbench import import_open3d, open_dataset, read_kitti_bin

KITTI = "kitti00_frames0-1/000000.bin"
KITTI_INTENSITY = "kitti_object_000008/000008.bin"  # has intensity; cropped to +-45 deg ahead
GROUND_Z = -(1.73 - 0.25)
DECILES = (10, 20, 30, 40, 50, 60, 70, 80, 90)


def scan_stats(points: np.ndarray) -> dict[str, float]:
    r = np.linalg.norm(points, axis=1)
    return {
        "points": float(len(points)),
        "ground": float(np.mean(points[:, 2] < GROUND_Z)),
        "above": float(np.mean(points[:, 2] > 0)),
        "far20": float(np.mean(r > 20)),
        **{f"r{q}": float(v) for q, v in zip(DECILES, np.percentile(r, DECILES), strict=True)},
    }


def _row(name: str, stats: list[dict[str, float]]) -> str:
    m = {k: float(np.mean([s[k] for s in stats])) for k in stats[0]}
    deciles = " / ".join(f"{m[f'r{q}']:.1f}" for q in DECILES)
    return (
        f"| {name} | {m['points']:,.0f} | {deciles} | {100 * m['ground']:.1f} % | "
        f"{100 * m['above']:.1f} % | {100 * m['far20']:.1f} % |"
    )


def icp_error(source: np.ndarray, target: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Translation (m) and rotation (deg) error of point-to-plane ICP aligning ``source`` onto
    ``target`` from the identity, against the true transform ``truth``."""
    o3d = import_open3d()

    def cloud(p: np.ndarray):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p.astype(np.float64))).voxel_down_sample(0.25)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.8, max_nn=30))
        return pc

    reg = o3d.pipelines.registration
    est = reg.registration_icp(
        cloud(source), cloud(target), 1.0, np.eye(4), reg.TransformationEstimationPointToPlane(),
        reg.ICPConvergenceCriteria(max_iteration=60),
    ).transformation
    err = np.linalg.inv(truth) @ est
    angle = np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(err[:3, 3])), float(angle)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", type=Path, required=True, help="the folder of real samples (shared/data/real)")
    ap.add_argument("--every", type=int, default=10, help="use every N-th simulated frame")
    args = ap.parse_args(argv)
    args.kitti = args.real / KITTI
    kitti_intensity = args.real / KITTI_INTENSITY

    print("| scans | points/scan | range deciles 10..90 % (m) | ground | z > 0 | r > 20 m |")
    print("|---|---|---|---|---|---|")
    if args.kitti.exists():
        print(_row(f"KITTI 00 `{args.kitti.name}` (real)", [scan_stats(read_kitti_bin(args.kitti).points)]))
    urban = open_dataset("sim", {"scene": "urban", "frames": 0, "cache": False})
    idx = range(0, len(urban), args.every)
    print(_row(f"sim urban, HDL-64E, {len(idx)} scans", [scan_stats(urban.simulate(i).points) for i in idx]))

    print()
    print("| scene | sensor | scans | points/scan min / median / mean / max |")
    print("|---|---|---|---|")
    for scene in ("tunnel", "indoor", "urban"):
        # The tunnel from outside its portal, like the paper's runs; the others from their start.
        ds = open_dataset("sim", {"scene": scene, "frames": 0, "start": 0.0 if scene == "tunnel" else None,
                                  "cache": False})
        counts = np.array([len(ds.simulate(i).points) for i in range(0, len(ds), max(1, args.every // 2))])
        print(
            f"| {scene} | {ds.sensor.name} ({ds.sensor.n_rays:,} rays) | {len(counts)} of {len(ds)} | "
            f"{counts.min():,} / {np.median(counts):,.0f} / {counts.mean():,.0f} / {counts.max():,} |"
        )


    if kitti_intensity.exists():
        real = read_kitti_bin(kitti_intensity)
        sim = urban.simulate(0)
        azimuth = np.arctan2(sim.points[:, 1], sim.points[:, 0])
        ahead = (sim.points[:, 0] > 0) & (np.abs(azimuth) < np.radians(45))
        print()
        print("| intensity | points | quartiles 10/25/50/75/90 % | mean | median ground / other |")
        print("|---|---|---|---|---|")
        for name, pts, inten in (
            (f"KITTI object `{kitti_intensity.name}` (real, camera view)", real.points, real.intensity),
            ("sim urban frame 0, +-45 deg ahead", sim.points[ahead], sim.intensity[ahead]),
        ):
            q = " / ".join(f"{v:.2f}" for v in np.percentile(inten, [10, 25, 50, 75, 90]))
            g = pts[:, 2] < GROUND_Z
            print(f"| {name} | {len(pts):,} | {q} | {inten.mean():.2f} | "
                  f"{np.median(inten[g]):.2f} / {np.median(inten[~g]):.2f} |")

    errors = []
    for i in range(0, len(urban) - 1, args.every):
        a, b = urban.simulate(i), urban.simulate(i + 1)
        errors.append(icp_error(b.points, a.points, np.linalg.inv(urban.poses[i]) @ urban.poses[i + 1]))
    e = np.array(errors)
    print()
    print(
        f"ICP between consecutive urban scans ({len(e)} pairs, every {args.every}th frame): translation "
        f"error mean {100 * e[:, 0].mean():.2f} cm, max {100 * e[:, 0].max():.2f} cm; rotation error "
        f"mean {e[:, 1].mean():.3f} deg, max {e[:, 1].max():.3f} deg"
    )


if __name__ == "__main__":
    main()
