"""Built-in file loaders: KITTI odometry folders and folders (or single files) of PCD/PLY/BIN.

They are registered through the ``lwbench`` entry point ``files`` like any plugin. Each loader
is one small class; the choice of sensor model is shared:

- ``sensor=auto`` (default): ``sensor.json`` beside the scans (written by lwbench), else an
  Ouster ``sensor_metadata.json``, else a model derived from the first scan
  (:meth:`SensorModel.from_points`, using the ``ring`` field when the files have one);
- ``sensor=<preset>``: one of the presets (``vlp16``, ``hdl64e``, ``os1-128``).
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np

from lwbench.dataset import Dataset
from lwbench.hookspecs import hookimpl
from lwbench.io import (
    SENSOR_FILE,
    DataFormatError,
    ScanArrays,
    read_kitti_bin,
    read_kitti_calib,
    read_kitti_poses,
    read_ouster_metadata,
    read_point_file,
    read_pose_file,
)
from lwbench.sensor import SensorModel, get_sensor
from lwbench.types import Frame, Param

__all__ = ["KittiDataset", "PointFileDataset"]

_SENSOR_PARAM = Param("sensor", "str", "auto", "sensor model: auto or a preset name")
_RATE_PARAM = Param("rate_hz", "float", 10.0, "frame rate, when the data does not say", low=0.01)
POINT_SUFFIXES = (".pcd", ".ply", ".bin")


def _sensor_for(folder: Path, name: str, first: ScanArrays, rate_hz: float) -> SensorModel:
    if name != "auto":
        return get_sensor(name)
    if (folder / SENSOR_FILE).exists():
        return SensorModel.from_dict(json.loads((folder / SENSOR_FILE).read_text()))
    if (folder / "sensor_metadata.json").exists():
        return read_ouster_metadata(folder / "sensor_metadata.json")
    return SensorModel.from_points(first.points, ring=first.ring, rate_hz=rate_hz, name="derived")


def _frame(scan: ScanArrays, sensor: SensorModel, index: int, stamp: float, pose) -> Frame:
    return Frame(
        scan.points,
        sensor,
        index=index,
        timestamp=stamp,
        pose=pose,
        intensity=scan.intensity,
        ring=scan.ring,
        time=scan.time,
    )


class _ScanFiles(Dataset):
    """What both loaders share: a sorted list of scan files, optional poses, one sensor model.

    Subclasses set ``files``, ``folder`` and ``poses`` in ``__init__`` and name their reader."""

    files: list[Path]
    folder: Path
    poses: np.ndarray | None

    @staticmethod
    def read(path: Path) -> ScanArrays:
        return read_point_file(path)

    def __len__(self) -> int:
        return len(self.files)

    @property
    def has_poses(self) -> bool:
        return self.poses is not None

    @cached_property
    def sensor(self) -> SensorModel:
        return _sensor_for(self.folder, self.config["sensor"], self.read(self.files[0]), self.config["rate_hz"])

    def _stamp(self, index: int) -> float:
        return index / self.sensor.rate_hz

    def frame(self, index: int) -> Frame:
        pose = self.poses[index] if self.poses is not None else None
        return _frame(self.read(self.files[index]), self.sensor, index, self._stamp(index), pose)


class KittiDataset(_ScanFiles):
    """KITTI odometry layout: ``velodyne/*.bin`` (or ``*.bin`` in the folder itself),
    optional ``poses.txt`` (camera frame) + ``calib.txt`` (``Tr``) and ``times.txt``.

    KITTI's ground truth is the left camera's pose; the LiDAR's is ``Tr^-1 · P · Tr``. Without
    ``calib.txt`` the poses are taken as sensor poses (as lwbench and Ouster samples write them).
    """

    name = "kitti"
    description = "KITTI odometry folder (velodyne .bin + poses.txt + calib.txt)"
    params = (
        Param("path", "str", None, "sequence folder"),
        _SENSOR_PARAM,
        _RATE_PARAM,
    )

    def __init__(self, **params) -> None:
        super().__init__(**params)
        if not self.config["path"]:
            raise DataFormatError("kitti: the path parameter is required")
        self.root = self.folder = Path(self.config["path"])
        scan_dir = self.root / "velodyne" if (self.root / "velodyne").is_dir() else self.root
        self.files = sorted(scan_dir.glob("*.bin"))
        if not self.files:
            raise DataFormatError(f"kitti: no .bin scans in {scan_dir}")
        self.poses = self._load_poses()
        times = self.root / "times.txt"
        self.times = np.loadtxt(times, ndmin=1) if times.exists() else None

    def _load_poses(self) -> np.ndarray | None:
        path = self.root / "poses.txt"
        if not path.exists():
            return None
        poses = read_kitti_poses(path)
        if len(poses) < len(self.files):
            raise DataFormatError(f"kitti: {len(poses)} poses for {len(self.files)} scans in {path}")
        calib = self.root / "calib.txt"
        tr = read_kitti_calib(calib) if calib.exists() else None
        if tr is not None:
            poses = np.linalg.inv(tr) @ poses @ tr
        return poses

    @classmethod
    def sniff(cls, path: Path) -> bool:
        return path.is_dir() and (any(path.glob("*.bin")) or any((path / "velodyne").glob("*.bin")))

    @staticmethod
    def read(path: Path) -> ScanArrays:
        return read_kitti_bin(path)

    def _stamp(self, index: int) -> float:
        return float(self.times[index]) if self.times is not None else super()._stamp(index)


class PointFileDataset(_ScanFiles):
    """A folder of PCD/PLY/BIN scans (sorted by name), or one scan file, with an optional pose
    file (``poses_file``; default: the one ``*pose*.txt`` in the folder, if exactly one).
    KITTI, TUM and stamped-KITTI pose files are recognised; keyed files are matched to scans
    by file stem (or by order when the keys are time stamps)."""

    name = "files"
    description = "folder of PCD/PLY/BIN scans or a single scan file, optional KITTI/TUM poses"
    params = (
        Param("path", "str", None, "folder or file"),
        Param("poses_file", "str", None, "pose file (KITTI 3x4 rows or TUM)"),
        _SENSOR_PARAM,
        _RATE_PARAM,
    )

    def __init__(self, **params) -> None:
        super().__init__(**params)
        if not self.config["path"]:
            raise DataFormatError("files: the path parameter is required")
        self.root = Path(self.config["path"])
        if self.root.is_file():
            self.files = [self.root]
            self.folder = self.root.parent
        else:
            self.folder = self.root
            self.files = sorted(p for p in self.root.iterdir() if p.suffix.lower() in POINT_SUFFIXES)
        if not self.files:
            raise DataFormatError(f"files: no {'/'.join(POINT_SUFFIXES)} scans in {self.root}")
        self.poses = self._load_poses()

    def _load_poses(self) -> np.ndarray | None:
        given = self.config["poses_file"]
        if given:
            path = Path(given)
        elif self.root.is_dir():
            candidates = sorted(self.folder.glob("*pose*.txt"))
            if len(candidates) != 1:
                return None
            path = candidates[0]
        else:
            return None
        keys, poses = read_pose_file(path)
        if keys is not None:
            by_key = dict(zip(keys, poses, strict=True))
            stems = [f.stem for f in self.files]
            if all(s in by_key for s in stems):
                return np.stack([by_key[s] for s in stems])
        if len(poses) != len(self.files):
            raise DataFormatError(f"files: {len(poses)} poses in {path} for {len(self.files)} scans")
        return poses

    @classmethod
    def sniff(cls, path: Path) -> bool:
        if path.is_file():
            return path.suffix.lower() in POINT_SUFFIXES
        return path.is_dir() and any(p.suffix.lower() in (".pcd", ".ply") for p in path.iterdir())


@hookimpl
def lwbench_datasets() -> list[type[Dataset]]:
    return [KittiDataset, PointFileDataset]
