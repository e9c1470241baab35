"""Reading and writing scans and poses on disk (KITTI layout, PCD/PLY, pose files).

Readers return plain arrays; the dataset classes in :mod:`lwbench.datasets` turn them into
frames. The KITTI writer is what ``lwbench simulate`` and the simulator's cache use, so a
simulated sequence can be fed to any KITTI-reading tool.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.deps import import_open3d
from lwbench.errors import DataFormatError
from lwbench.sensor import SensorModel
from lwbench.types import Frame

__all__ = [
    "ScanArrays",
    "read_kitti_bin",
    "read_point_file",
    "read_kitti_poses",
    "read_kitti_calib",
    "read_pose_file",
    "read_ouster_metadata",
    "write_kitti_sequence",
    "SENSOR_FILE",
]

SENSOR_FILE = "sensor.json"  # lwbench's addition to the KITTI layout: the sensor model


@dataclass
class ScanArrays:
    points: np.ndarray
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None

    def finite(self) -> ScanArrays:
        """Drop non-returns (NaN/inf rows, as organized clouds store them) and all-zero rows."""
        keep = np.isfinite(self.points).all(axis=1) & np.any(self.points != 0, axis=1)
        if keep.all():
            return self

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[keep]

        return ScanArrays(self.points[keep], pick(self.intensity), pick(self.ring), pick(self.time))


def _median_step(pts: np.ndarray) -> float:
    sample = pts[: min(len(pts), 20000)]
    if len(sample) < 2:
        return 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        return float(np.nanmedian(np.linalg.norm(np.diff(sample, axis=0), axis=1)))


def read_kitti_bin(path: str | Path) -> ScanArrays:
    """A KITTI velodyne ``.bin``: float32 x,y,z,intensity (16 B/point) or x,y,z (12 B/point).

    When the size divides by both 12 and 16 the layout is ambiguous; the right reading is the
    one where consecutive points (in firing order) are close together -- the wrong one shuffles
    intensities into coordinates and makes neighbours metres apart.
    """
    raw = np.fromfile(path, dtype="<f4")
    n = raw.size
    if n == 0:
        return ScanArrays(np.zeros((0, 3), np.float32))
    options = [c for c in (4, 3) if n % c == 0]
    if not options:
        raise DataFormatError(f"{path}: {n * 4} bytes is neither N x 12 nor N x 16 float32")
    if len(options) == 2:
        steps = {c: _median_step(raw.reshape(-1, c)[:, :3]) for c in options}
        cols = min(steps, key=steps.get)
    else:
        cols = options[0]
    arr = raw.reshape(-1, cols)
    return ScanArrays(np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3]) if cols == 4 else None).finite()


def read_point_file(path: str | Path) -> ScanArrays:
    """A PCD or PLY file through Open3D's tensor reader, which keeps intensity, ring and
    timestamp fields (the legacy reader drops them) and reads PCD ``binary_compressed``."""
    o3d = import_open3d()

    path = Path(path)
    if path.suffix.lower() == ".bin":
        return read_kitti_bin(path)
    pc = o3d.t.io.read_point_cloud(str(path))
    if "positions" not in pc.point or pc.point.positions.shape[0] == 0:
        if path.stat().st_size > 200:
            raise DataFormatError(f"{path}: Open3D read no points from this file")
        return ScanArrays(np.zeros((0, 3), np.float32))
    fields = {k: pc.point[k].numpy() for k in pc.point}
    pts = fields["positions"].astype(np.float32)

    def field(*names: str) -> np.ndarray | None:
        for n in names:
            if n in fields:
                return fields[n].reshape(-1)
        return None

    return ScanArrays(
        pts,
        field("intensity", "intensities", "reflectivity"),
        field("ring", "rings"),
        field("timestamp", "time", "t"),
    ).finite()


def _rows_to_poses(rows: np.ndarray) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    return poses


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """``poses.txt``: one row of 12 numbers (3x4, row-major) per frame -> ``(N, 4, 4)``."""
    rows = np.loadtxt(path, ndmin=2)
    if rows.shape[1] != 12:
        raise DataFormatError(f"{path}: expected 12 numbers per line, got {rows.shape[1]}")
    return _rows_to_poses(rows)


def read_kitti_calib(path: str | Path) -> np.ndarray | None:
    """The ``Tr`` (velodyne -> camera) transform of a KITTI odometry ``calib.txt``, if present."""
    for line in Path(path).read_text().splitlines():
        key, _, values = line.partition(":")
        if key.strip() in ("Tr", "Tr_velo_to_cam"):
            t = np.eye(4)
            t[:3, :4] = np.array(values.split(), dtype=np.float64).reshape(3, 4)
            return t
    return None


def read_pose_file(path: str | Path) -> tuple[list[str] | None, np.ndarray]:
    """A pose file in any of the layouts real datasets use, detected from its columns:

    - 12 numbers: KITTI (3x4 row-major), one line per frame in order;
    - 8 numbers: TUM (``stamp tx ty tz qx qy qz qw``);
    - a key then 12 numbers: stamped KITTI (key = file stem or time stamp);
    - a key then 7 numbers: TUM with a non-numeric stamp.

    Returns the per-line keys (``None`` for plain KITTI) and ``(N, 4, 4)`` poses.
    """
    from scipy.spatial.transform import Rotation

    lines = [ln.split() for ln in Path(path).read_text().splitlines() if ln.strip() and ln[0] != "#"]
    if not lines:
        raise DataFormatError(f"{path}: empty pose file")
    width = {len(ln) for ln in lines}
    if len(width) != 1:
        raise DataFormatError(f"{path}: lines have different numbers of fields {sorted(width)}")
    (w,) = width
    if w == 12:
        return None, _rows_to_poses(np.array(lines, dtype=np.float64))
    keys = [ln[0] for ln in lines]
    vals = np.array([ln[1:] for ln in lines], dtype=np.float64)
    if w == 13:
        return keys, _rows_to_poses(vals)
    if w == 8:
        poses = np.tile(np.eye(4), (len(vals), 1, 1))
        poses[:, :3, 3] = vals[:, :3]
        poses[:, :3, :3] = Rotation.from_quat(vals[:, 3:7]).as_matrix()
        return keys, poses
    raise DataFormatError(f"{path}: {w} fields per line is neither KITTI (12) nor TUM (8)")


def read_ouster_metadata(path: str | Path, *, max_range: float = 120.0) -> SensorModel:
    """A sensor model from an Ouster ``sensor_metadata.json`` (its own beam table)."""
    meta = json.loads(Path(path).read_text())
    cols = int(meta.get("data_format", {}).get("columns_per_frame", 1024))
    mode = str(meta.get("lidar_mode", f"{cols}x10"))
    rate = float(mode.split("x")[1]) if "x" in mode else 10.0
    return SensorModel(
        name=str(meta.get("prod_line", "ouster")).lower(),
        elevations_deg=tuple(float(a) for a in meta["beam_altitude_angles"]),
        azimuth_step_deg=360.0 / cols,
        min_range=0.3,
        max_range=max_range,
        rate_hz=rate,
    )


def write_kitti_sequence(frames: list[Frame], out_dir: str | Path) -> Path:
    """Write frames in the KITTI odometry layout that :class:`KittiDataset` (and other tools)
    read: ``velodyne/NNNNNN.bin`` (x,y,z,intensity float32), ``poses.txt`` (sensor -> world,
    so ``calib.txt`` holds an identity ``Tr``), ``times.txt`` and ``sensor.json``.
    """
    out = Path(out_dir)
    (out / "velodyne").mkdir(parents=True, exist_ok=True)
    poses, times = [], []
    for i, f in enumerate(frames):
        inten = f.intensity if f.intensity is not None else np.zeros(len(f), np.float32)
        xyzi = np.column_stack([f.points, inten.astype(np.float32)]).astype("<f4")
        xyzi.tofile(out / "velodyne" / f"{i:06d}.bin")
        times.append(f.timestamp)
        if f.pose is not None:
            poses.append(f.pose[:3, :4].reshape(-1))
    if poses and len(poses) == len(frames):
        np.savetxt(out / "poses.txt", np.array(poses), fmt="%.9e")
        _write_identity_calib(out / "calib.txt")
    np.savetxt(out / "times.txt", np.array(times), fmt="%.6f")
    if frames:
        (out / SENSOR_FILE).write_text(json.dumps(frames[0].sensor.to_dict(full=True), indent=1))
    return out


def _write_identity_calib(path: Path) -> None:
    path.write_text("Tr: " + " ".join(f"{v:.1f}" for v in np.eye(4)[:3].reshape(-1)) + "\n")
