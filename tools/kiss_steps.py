"""Per-frame steps of KISS-ICP and of lwbench's odometry against the ground truth, on raw scans.

    python tools/kiss_steps.py [SCENE] [FRAMES] [KISS_MAX_RANGE]

SCENE is a sim scene (default urban), FRAMES the number of frames (default 20), KISS_MAX_RANGE
the kiss metric's ``max_range`` (default: the sensor's). Prints, per frame, the ground-truth step
length, each estimate's step length and each estimate's position error (m): what the ATE/RPE in
docs/task_metrics.md are made of.
"""

from __future__ import annotations

import argparse

import numpy as np
from lwbench_metrics.kiss import kiss_trajectory
from lwbench_metrics.localization import ICP_PARAMS, track_odometry

from lwbench import open_dataset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="urban", help="a sim scene")
    ap.add_argument("frames", nargs="?", type=int, default=20)
    ap.add_argument("max_range", nargs="?", type=float, help="the kiss metric's max_range (default: the sensor's)")
    args = ap.parse_args()
    scene, n = args.scene, args.frames
    ds = open_dataset("sim", {"scene": scene, "frames": n}, seed=0)
    frames = [ds[i] for i in range(n)]
    max_range = args.max_range if args.max_range is not None else frames[0].sensor.max_range
    gt = np.stack([f.pose for f in frames])
    scans = [f.points for f in frames]
    kiss = kiss_trajectory(scans, gt[0], max_range)
    odom = track_odometry(scans, gt[0], ICP_PARAMS).poses

    def steps(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.diff(p[:, :3, 3], axis=0), axis=1)

    def errors(p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p[:, :3, 3] - gt[:, :3, 3], axis=1)

    print(f"sim {scene}, {n} frames, KISS-ICP max_range {max_range:g} m")
    print("| frame | GT step | KISS step | odometry step | KISS error | odometry error |")
    print("|---|---|---|---|---|---|")
    for k, row in enumerate(zip(steps(gt), steps(kiss), steps(odom), errors(kiss)[1:], errors(odom)[1:], strict=True)):
        print(f"| {k + 1} | " + " | ".join(f"{v:.3f}" for v in row) + " |")


if __name__ == "__main__":
    main()
