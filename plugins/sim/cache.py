"""On-disk cache of simulated scans, in the KITTI odometry layout.

A sequence folder is readable by any KITTI tool (and by lwbench's ``kitti`` loader):
``velodyne/NNNNNN.bin`` (float32 x, y, z, intensity), ``poses.txt`` (sensor -> world, 3x4 rows),
``calib.txt`` (identity ``Tr``, since the poses are already the sensor's), ``times.txt`` and
``sensor.json``. Ring and per-point time, which KITTI has no place for, sit beside it as
``ring/NNNNNN.npy`` (uint16) and ``time/NNNNNN.npy`` (float32), read with ``allow_pickle=False``.

Scans are written one by one as they are first simulated, each file through a temporary name
and an atomic rename, so parallel workers and interrupted runs never leave a half-written scan.
The folder name hashes every parameter and the simulator version: a changed simulator never
reads old scans.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np

from lwbench import SENSOR_FILE, SensorModel

from .raycast import Scan


def cache_root() -> Path:
    """``$LWBENCH_CACHE/sim`` if set, else ``~/.cache/lwbench/sim``."""
    base = os.environ.get("LWBENCH_CACHE")
    return (Path(base) if base else Path.home() / ".cache" / "lwbench") / "sim"


def _atomic_write(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ScanCache:
    """One simulated sequence's folder."""

    def __init__(self, root: Path) -> None:
        self.root = root

    @classmethod
    def open(cls, key: str, poses: np.ndarray, times: np.ndarray, sensor: SensorModel) -> ScanCache | None:
        """The cache folder for ``key`` with its metadata written, or ``None`` (with a warning)
        when it cannot be created: the simulator then just recomputes scans."""
        root = cache_root() / key
        try:
            for sub in ("velodyne", "ring", "time"):
                (root / sub).mkdir(parents=True, exist_ok=True)
            if not (root / SENSOR_FILE).exists():
                rows = "".join(" ".join(f"{v:.9e}" for v in p[:3, :4].reshape(-1)) + "\n" for p in poses)
                _atomic_write(root / "poses.txt", lambda f: f.write(rows.encode()))
                calib = "Tr: " + " ".join(f"{v:.1f}" for v in np.eye(4)[:3].reshape(-1)) + "\n"
                _atomic_write(root / "calib.txt", lambda f: f.write(calib.encode()))
                stamps = "".join(f"{t:.6f}\n" for t in times)
                _atomic_write(root / "times.txt", lambda f: f.write(stamps.encode()))
                desc = json.dumps(sensor.to_dict(full=True), indent=1)
                _atomic_write(root / SENSOR_FILE, lambda f: f.write(desc.encode()))
        except OSError as e:
            warnings.warn(f"sim: cannot use the scan cache at {root} ({e}); not caching", stacklevel=3)
            return None
        return cls(root)

    def _paths(self, index: int) -> tuple[Path, Path, Path]:
        name = f"{index:06d}"
        return (
            self.root / "velodyne" / f"{name}.bin",
            self.root / "ring" / f"{name}.npy",
            self.root / "time" / f"{name}.npy",
        )

    def load(self, index: int) -> Scan | None:
        """The cached scan, or ``None`` when it is missing or inconsistent (then re-simulated)."""
        bin_path, ring_path, time_path = self._paths(index)
        try:
            xyzi = np.fromfile(bin_path, dtype="<f4")
            ring = np.load(ring_path, allow_pickle=False)
            time = np.load(time_path, allow_pickle=False)
        except (OSError, ValueError):
            return None
        if xyzi.size % 4 or ring.shape != (xyzi.size // 4,) or time.shape != ring.shape:
            return None
        xyzi = xyzi.reshape(-1, 4)
        return Scan(
            np.ascontiguousarray(xyzi[:, :3], dtype=np.float32),
            np.ascontiguousarray(xyzi[:, 3], dtype=np.float32),
            ring.astype(np.uint16, copy=False),
            time.astype(np.float32, copy=False),
        )

    def store(self, index: int, scan: Scan) -> None:
        bin_path, ring_path, time_path = self._paths(index)
        xyzi = np.column_stack([scan.points, scan.intensity]).astype("<f4")
        try:
            # The .bin goes last: load() needs all three, and a scan is complete once it exists.
            _atomic_write(ring_path, lambda f: np.save(f, scan.ring, allow_pickle=False))
            _atomic_write(time_path, lambda f: np.save(f, scan.time, allow_pickle=False))
            _atomic_write(bin_path, lambda f: xyzi.tofile(f))
        except OSError as e:
            warnings.warn(f"sim: could not cache scan {index} in {self.root} ({e})", stacklevel=2)
