"""Writing frames in the KITTI odometry layout (``lwbench simulate``, the simulator's cache)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from lwbench.frame import Frame
from lwbench.io.sensor_files import SENSOR_FILE

__all__ = ["write_kitti_sequence"]


def write_kitti_sequence(frames: Iterable[Frame], out_dir: str | Path) -> Path:
    """Write frames in the KITTI odometry layout that :class:`KittiDataset` (and other tools)
    read: ``velodyne/NNNNNN.bin`` (x,y,z,intensity float32), ``poses.txt`` (sensor -> world,
    so ``calib.txt`` holds an identity ``Tr``), ``times.txt`` and ``sensor.json``.

    ``frames`` may be a generator: each scan is written as it comes and not kept (a simulated
    town drive is 2,000 scans, 5 GB of them in memory)."""
    out = Path(out_dir)
    (out / "velodyne").mkdir(parents=True, exist_ok=True)
    poses, times = [], []
    n, first = 0, None
    for i, f in enumerate(frames):
        inten = f.intensity if f.intensity is not None else np.zeros(len(f), np.float32)
        xyzi = np.column_stack([f.points, inten.astype(np.float32)]).astype("<f4")
        xyzi.tofile(out / "velodyne" / f"{i:06d}.bin")
        times.append(f.timestamp)
        if f.pose is not None:
            poses.append(f.pose[:3, :4].reshape(-1))
        if first is None:
            first = f.sensor
        n += 1
    if poses and len(poses) == n:
        np.savetxt(out / "poses.txt", np.array(poses), fmt="%.9e")
        _write_identity_calib(out / "calib.txt")
    np.savetxt(out / "times.txt", np.array(times), fmt="%.6f")
    if first is not None:
        (out / SENSOR_FILE).write_text(json.dumps(first.to_dict(full=True), indent=1))
    return out


def _write_identity_calib(path: Path) -> None:
    path.write_text("Tr: " + " ".join(f"{v:.1f}" for v in np.eye(4)[:3].reshape(-1)) + "\n")
