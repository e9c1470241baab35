"""Built-in file loaders: KITTI odometry folders and folders (or single files) of scans.

They are registered through the ``lwbench`` entry point ``files`` like any plugin and import
only lwbench's public API (``lwbench``, ``lwbench.io``), as a third-party loader would. Each
loader is one small class; what they share is how scans are picked from a folder
(:mod:`.scan_picking`) and how the sensor model is chosen.

The ``sensor`` parameter:

- ``auto`` (default): ``sensor.json`` beside the scans (written by lwbench), else an Ouster
  ``sensor_metadata.json``, else a model derived from the first scan
  (:func:`lwbench.derive_sensor`: the ``ring`` field, else the point order, else -- with
  a warning, as a guess -- a preset's table that fits, the elevation histogram, a uniform grid).
  Every later scan is then checked to come from the same sensor (a folder that mixes sensors
  fails on the first scan that does not match) and to lie in the model's range window (a
  warning names the returns outside it);
- a preset name (``vlp16``, ``hdl64e``, ``os1-128``, ... :data:`lwbench.SENSOR_PRESETS`);
- a path to an lwbench ``sensor.json`` or an Ouster ``sensor_metadata.json``.

Whether the model was guessed is :attr:`SensorChoice.guessed` (and ``sensor_guessed`` on each
dataset): exact for a ring field, a usable point order, a sensor file or a named preset; guessed
otherwise. Results scored on a guessed model should carry that mark.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lwbench import (
    SENSOR_PRESETS,
    DataFormatError,
    Dataset,
    DataWarning,
    Derivation,
    Frame,
    Param,
    ParameterError,
    SensorModel,
    derive_sensor,
    get_sensor,
    outside_range_window,
    sensor_mismatch,
)
from lwbench.io import (
    BIN_LAYOUTS,
    NUSCENES_SUFFIX,
    SCAN_SUFFIXES,
    SENSOR_FILE,
    ScanArrays,
    read_kitti_bin,
    read_kitti_calib,
    read_kitti_poses,
    read_point_file,
    read_pose_file,
    read_sensor_file,
    read_times,
    scan_suffix,
)

from .scan_picking import pick_scans, read_time_sidecar, rows_for, time_sidecars

__all__ = ["KittiDataset", "PointFileDataset", "SensorChoice", "pick_scans", "KITTI_LAYOUTS"]

_SENSOR_PARAM = Param(
    "sensor", "str", "auto", "sensor model: auto, a preset name, or a sensor.json / Ouster sensor_metadata.json path"
)
_RATE_PARAM = Param("rate_hz", "float", 10.0, "frame rate, when the data does not say", low=0.01)
_FIELDS_PARAM = Param(
    "fields", "str", "auto", "record layout of .bin scans (auto: the one plausible reading)",
    choices=("auto", *BIN_LAYOUTS),
)
_MAX_RANGE_PARAM = Param(
    "max_range", "float", None, "max range (m) of a derived sensor model (default: the first scan's farthest return)",
    low=0.1,
)
POINT_SUFFIXES = SCAN_SUFFIXES
KITTI_LAYOUTS = (
    "layouts that load: SEQ/velodyne/NNNNNN.bin (+ SEQ/poses.txt, calib.txt, times.txt); the official "
    "odometry tree ROOT/sequences/NN/velodyne/NNNNNN.bin + ROOT/poses/NN.txt (path=ROOT/sequences/NN, or "
    "path=ROOT with sequence=NN); a folder of .bin scans named one way (NNNNNN.bin)"
)
FILES_LAYOUTS = (
    "layouts that load: one scan file (.pcd, .ply, .xyz, .vtk, .bin, nuScenes .pcd.bin) or a folder of such "
    "scans named one way, with an optional pose file (*pose*.txt or poses_file=...)"
)
# What every loader of scans on disk declares beside its path.
_SCAN_PARAMS = (_SENSOR_PARAM, _RATE_PARAM, _FIELDS_PARAM, _MAX_RANGE_PARAM)


def _required_path(loader: str, path: str | None) -> Path:
    if not path:
        raise DataFormatError(f"{loader}: the path parameter is required")
    return Path(path)


# ---------------------------------------------------------------------------- sensor choice
@dataclass(frozen=True)
class SensorChoice:
    """The dataset's sensor model and where it came from (for ``lwbench inspect``)."""

    sensor: SensorModel
    source: str
    derivation: Derivation | None = None
    derived_from: Path | None = None

    @property
    def guessed(self) -> bool:
        """Whether the model is a guess (derived without ring labels): results scored on it
        should say so. A sensor file, a named preset, a ring field or a point order is exact."""
        return self.derivation is not None and self.derivation.guessed

    def describe(self) -> dict[str, Any]:
        info: dict[str, Any] = {"sensor source": self.source, "sensor guessed": self.guessed}
        if self.derivation is not None:
            info["derived sensor"] = self.derivation.describe()
        return info


def _choose_sensor(value: str, folder: Path, first: Path, read, rate_hz: float,
                   max_range: float | None = None) -> SensorChoice:
    if value == "auto":
        for name in (SENSOR_FILE, "sensor_metadata.json"):
            if (folder / name).is_file():
                return SensorChoice(read_sensor_file(folder / name), f"{name} beside the scans")
        scan = read(first)
        if len(scan.points) < 100:
            raise DataFormatError(
                f"{first}: {len(scan.points)} points is too few to derive a sensor model from; "
                "pass --dataset-param sensor=<preset or sensor.json path>"
            )
        try:
            d = derive_sensor(scan.points, ring=scan.ring, rate_hz=rate_hz, name="derived")
        except ValueError as exc:  # no plausible sensor fits the scan (lwbench.sensors.model's bounds)
            raise DataFormatError(f"{first}: no sensor model can be derived from this scan ({exc}); "
                                  "pass --dataset-param sensor=<preset or sensor.json path>") from None
        if max_range is not None and max_range > d.sensor.min_range:
            d = Derivation(d.sensor.with_max_range(max_range), d.method, d.stats, d.warnings, d.notes, d.rule)
        return SensorChoice(d.sensor, f"derived from {first.name} ({d.method})", d, first)
    if value.lower() in SENSOR_PRESETS:
        return SensorChoice(get_sensor(value), f"preset {value.lower()}")
    path = Path(value).expanduser()
    if not path.is_file() and not path.is_absolute() and (folder / path).is_file():
        path = folder / path
    if path.is_file():
        return SensorChoice(read_sensor_file(path), f"file {path}")
    raise ParameterError(
        f"sensor={value!r}: neither a preset ({', '.join(sorted(SENSOR_PRESETS))}), auto, nor an existing "
        "sensor.json / sensor_metadata.json file"
    )


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

    Subclasses set ``files``, ``folder``, ``poses`` (and ``skipped``, ``layout``, ``pose_source``)
    in ``__init__`` and name their reader."""

    files: list[Path]
    folder: Path
    poses: np.ndarray | None
    skipped: list[Path]
    layout: str
    pose_source: str | None

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.skipped, self.pose_source = [], None
        self.time_files: dict[Path, Path] = {}  # per-point time sidecars (times_NN.bin beside raw_NN.bin)
        self._checked: set[int] = set()

    def read(self, path: Path) -> ScanArrays:
        return read_point_file(path, fields=self.config["fields"])

    def _named_sensor_now(self) -> None:
        """A sensor the user named (preset, file) is resolved at once, so a typo is one clear
        error from the constructor rather than a failure on every frame."""
        if self.config["sensor"] != "auto":
            _ = self.sensor_choice

    def __len__(self) -> int:
        return len(self.files)

    @property
    def has_poses(self) -> bool:
        return self.poses is not None

    @cached_property
    def sensor_choice(self) -> SensorChoice:
        return _choose_sensor(self.config["sensor"], self.folder, self.files[0], self.read, self.config["rate_hz"],
                              self.config["max_range"])

    @property
    def sensor(self) -> SensorModel:
        return self.sensor_choice.sensor

    @property
    def sensor_guessed(self) -> bool:
        """Whether the dataset's sensor model is a guess (:attr:`SensorChoice.guessed`)."""
        return self.sensor_choice.guessed

    def _stamp(self, index: int) -> float:
        return index / self.sensor.rate_hz

    def _check_same_sensor(self, index: int, scan: ScanArrays) -> None:
        """A scan's own derived model against the one derived from the first scan: a folder of
        two sensors must not silently share the first one's grid. Costs one derivation per scan,
        once (~60 ms on a 120k-point scan; a guessed model is checked against the histogram's
        quick guess, ~20 ms, not the full one's ~1 s)."""
        choice = self.sensor_choice
        if choice.derivation is None or index in self._checked or self.files[index] == choice.derived_from:
            return
        outside = outside_range_window(scan.points, self.sensor)
        if outside is not None:
            warnings.warn(
                f"{self.name}: {self.files[index].name}: {outside}, outside the range window of the model derived "
                f"from {choice.derived_from.name} -- grid codecs (rangeimage, VSGP) drop them and the range metrics "
                "leave out returns nearer than the min range; name the sensor (--dataset-param sensor=...), or for "
                "far returns widen the window with --dataset-param max_range=M",
                DataWarning,
                stacklevel=3,
            )
        if len(scan.points) >= 100:
            mine = derive_sensor(scan.points, ring=scan.ring, rate_hz=self.sensor.rate_hz, warn=False,
                                 quick=choice.guessed)
            why = sensor_mismatch(choice.derivation, mine)
            if why is not None:
                first = choice.derivation

                def what(d: Derivation) -> str:
                    return f"{d.sensor.n_beams} beams, {d.sensor.azimuth_step_deg:.4f} deg azimuth step ({d.method})"

                raise DataFormatError(
                    f"{self.name}: {self.files[index].name} is not from the sensor of {choice.derived_from.name}, "
                    f"whose derived model this dataset uses ({what(first)}); {self.files[index].name}: "
                    f"{what(mine)} -- {why}. Keep one sensor's scans per folder, or name the sensor with "
                    "--dataset-param sensor=<preset or sensor.json path>"
                )
        self._checked.add(index)

    def _read_scan(self, path: Path) -> ScanArrays:
        sidecar = self.time_files.get(path)
        if sidecar is None:
            return self.read(path)
        scan = read_kitti_bin(path, self.config["fields"], drop_non_returns=False)
        return ScanArrays(scan.points, scan.intensity, scan.ring, read_time_sidecar(sidecar, len(scan.points))).finite()

    def why_no_poses(self) -> str:
        if self.folder.name == "velodyne":
            return (f"{self.folder} is a velodyne/ folder: point at its parent, where poses.txt and calib.txt "
                    "live (or poses/NN.txt of the odometry tree)")
        return (f"no poses file beside the scans in {self.folder} (KITTI: poses.txt next to velodyne/; a folder of "
                "scan files: one *pose*.txt or --dataset-param poses_file=PATH; see docs/datasets.md)")

    def pose(self, index: int) -> np.ndarray | None:
        """From the poses file: no scan is read."""
        if self.poses is None:
            return None
        return self.poses[index % len(self)]

    def frame(self, index: int) -> Frame:
        scan = self._read_scan(self.files[index])
        self._check_same_sensor(index, scan)
        pose = self.poses[index] if self.poses is not None else None
        return _frame(scan, self.sensor, index, self._stamp(index), pose)

    def frame_origin(self, index: int) -> dict[str, Any]:
        """The scan file's stem names what is written from it (``000042.bin`` -> ``000042``)."""
        return {"name": _stem(self.files[index])}

    def source_info(self) -> dict[str, Any]:
        """How this dataset was read: layout, poses, skipped files and the sensor's source."""
        info: dict[str, Any] = {"layout": self.layout, "poses from": self.pose_source or "none"}
        read_as_times = set(self.time_files.values())
        skipped = [p.name for p in self.skipped if p not in read_as_times]
        if skipped:
            info["skipped files"] = skipped
        if self.time_files:
            first = next(iter(self.time_files.values())).name
            info["per-point times from"] = f"{len(self.time_files)} sidecar files ({first}, ...)"
        return {**info, **self.sensor_choice.describe()}


# ------------------------------------------------------------------------------------ KITTI
@dataclass(frozen=True)
class _KittiLayout:
    sequence_dir: Path
    scan_dir: Path
    poses: Path | None
    description: str


def _kitti_layout(root: Path, sequence: str | None) -> _KittiLayout:
    if sequence is not None:
        seqs = root / "sequences"
        seq = next((seqs / s for s in (sequence, sequence.zfill(2)) if (seqs / s).is_dir()), None)
        if seq is None:
            have = sorted(p.name for p in seqs.iterdir() if p.is_dir()) if seqs.is_dir() else []
            raise DataFormatError(
                f"kitti: no sequence {sequence!r} under {seqs}"
                + (f" (sequences: {', '.join(have)})" if have else "")
                + f"; {KITTI_LAYOUTS}"
            )
        poses = root / "poses" / f"{seq.name}.txt"
        return _KittiLayout(seq, seq / "velodyne", poses if poses.is_file() else None,
                            f"KITTI odometry tree, sequence {seq.name}")
    if (root / "velodyne").is_dir():
        poses = root / "poses.txt"
        official = root.parent.parent / "poses" / f"{root.name}.txt"
        if not poses.is_file() and root.parent.name == "sequences" and official.is_file():
            return _KittiLayout(root, root / "velodyne", official, f"KITTI odometry tree, sequence {root.name}")
        return _KittiLayout(root, root / "velodyne", poses if poses.is_file() else None, "KITTI sequence folder")
    if (root / "sequences").is_dir() and not any(scan_suffix(p) == ".bin" for p in root.iterdir()):
        have = sorted(p.name for p in (root / "sequences").iterdir() if (p / "velodyne").is_dir())
        raise DataFormatError(
            f"kitti: {root} is a KITTI odometry root (sequences {', '.join(have) or 'none with velodyne/'}); "
            f"pass --dataset-param sequence=NN or point at {root / 'sequences' / 'NN'}"
        )
    poses = root / "poses.txt"
    return _KittiLayout(root, root, poses if poses.is_file() else None, "folder of .bin scans")


class KittiDataset(_ScanFiles):
    """KITTI odometry layout: ``velodyne/NNNNNN.bin`` (or numbered ``*.bin`` in the folder
    itself), optional ``poses.txt`` (camera frame) + ``calib.txt`` (``Tr``) and ``times.txt``;
    or the official tree, ``sequences/NN`` with its poses in ``poses/NN.txt``.

    KITTI's ground truth is the left camera's pose; the LiDAR's is ``Tr^-1 · P · Tr``. Without
    ``calib.txt`` the poses are taken as sensor poses (as lwbench and Ouster samples write them).
    Numbered scans take the pose and time rows of their number.
    """

    name = "kitti"
    description = "KITTI odometry folder (velodyne .bin + poses.txt + calib.txt) or sequences/NN tree"
    params = (
        Param("path", "str", None, "sequence folder (or the odometry root, with sequence)"),
        Param("sequence", "str", None, "with path = the odometry root: the sequence (00..21)"),
        *_SCAN_PARAMS,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.root = _required_path(self.name, self.config["path"])
        if not self.root.is_dir():
            raise DataFormatError(f"kitti: {self.root} is not a folder; {KITTI_LAYOUTS}")
        layout = _kitti_layout(self.root, self.config["sequence"])
        self.folder, self.layout = layout.sequence_dir, layout.description
        candidates = [p for p in layout.scan_dir.iterdir() if p.is_file()] if layout.scan_dir.is_dir() else []
        self.files, self.skipped = pick_scans(
            [p for p in candidates if scan_suffix(p) in (".bin", NUSCENES_SUFFIX)], layout.scan_dir, "kitti"
        )
        if not self.files:
            raise DataFormatError(f"kitti: no .bin scans in {layout.scan_dir}; {KITTI_LAYOUTS}")
        self.time_files = time_sidecars(self.files, self.skipped)
        self.poses = self._load_poses(layout.poses)
        self._named_sensor_now()
        times = self.folder / "times.txt"
        self.times = None
        if times.is_file():
            stamps = read_times(times)
            self.times = stamps[rows_for(self.files, len(stamps), times, "kitti")]

    def _load_poses(self, path: Path | None) -> np.ndarray | None:
        if path is None:
            return None
        poses = read_kitti_poses(path)
        poses = poses[rows_for(self.files, len(poses), path, "kitti")]
        calib = self.folder / "calib.txt"
        tr = read_kitti_calib(calib) if calib.is_file() else None
        self.pose_source = f"{path}" + (" (camera frame; LiDAR pose via calib.txt Tr)" if tr is not None else "")
        if tr is not None:
            poses = np.linalg.inv(tr) @ poses @ tr
        return poses

    @classmethod
    def sniff(cls, path: Path) -> bool:
        if not path.is_dir():
            return False
        if (path / "velodyne").is_dir() or any((path / "sequences").glob("*/velodyne")):
            return True
        return any(scan_suffix(p) == ".bin" for p in path.iterdir())

    def read(self, path: Path) -> ScanArrays:
        return read_kitti_bin(path, self.config["fields"])

    def _stamp(self, index: int) -> float:
        return float(self.times[index]) if self.times is not None else super()._stamp(index)


# ------------------------------------------------------------------------------ point files
def _stem(path: Path) -> str:
    suffix = scan_suffix(path) or path.suffix
    return path.name[: len(path.name) - len(suffix)]


class PointFileDataset(_ScanFiles):
    """A folder of PCD/PLY/XYZ/VTK/BIN scans (one format and naming scheme, in natural order), or
    one scan file, with an optional pose file (``poses_file``; default: the one ``*pose*.txt`` in
    the folder, if exactly one). KITTI, TUM and stamped-KITTI pose files are recognised; keyed
    files are matched to scans by file stem (or by order when the keys are time stamps)."""

    name = "files"
    description = "folder of PCD/PLY/XYZ/VTK/BIN scans or a single scan file, optional KITTI/TUM poses"
    params = (
        Param("path", "str", None, "folder or file"),
        Param("poses_file", "str", None, "pose file (KITTI 3x4 rows or TUM)"),
        *_SCAN_PARAMS,
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.root = _required_path(self.name, self.config["path"])
        if self.root.is_file():
            if scan_suffix(self.root) is None:
                raise DataFormatError(f"files: {self.root} is not a scan file; {FILES_LAYOUTS}")
            self.files, self.folder, self.layout = [self.root], self.root.parent, "single scan file"
        elif self.root.is_dir():
            self.folder, self.layout = self.root, "folder of scan files"
            self.files, self.skipped = pick_scans([p for p in self.root.iterdir() if p.is_file()], self.root, "files")
            self.time_files = {s: t for s, t in time_sidecars(self.files, self.skipped).items()
                               if scan_suffix(s) == ".bin"}
        else:
            raise DataFormatError(f"files: {self.root} does not exist")
        if not self.files:
            raise DataFormatError(f"files: no scans in {self.root}; {FILES_LAYOUTS}")
        self.poses = self._load_poses()
        self._named_sensor_now()

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
        self.pose_source = str(path)
        if keys is not None:
            by_key = dict(zip(keys, poses, strict=True))
            stems = [_stem(f) for f in self.files]
            if all(s in by_key for s in stems):
                return np.stack([by_key[s] for s in stems])
        if len(poses) != len(self.files):
            raise DataFormatError(f"files: {len(poses)} poses in {path} for {len(self.files)} scans")
        return poses

    @classmethod
    def sniff(cls, path: Path) -> bool:
        if path.is_file():
            return scan_suffix(path) is not None
        return path.is_dir() and any(scan_suffix(p) not in (None, ".bin") for p in path.iterdir())

