"""Reading and writing scans and poses on disk (KITTI layout, PCD/PLY, pose files).

Readers return plain arrays; the dataset classes in :mod:`lwbench.loaders` turn them into
frames. The KITTI writer is what ``lwbench simulate`` and the simulator's cache use, so a
simulated sequence can be fed to any KITTI-reading tool.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench import Frame
from lwbench.deps import import_open3d
from lwbench.errors import DataFormatError, DataWarning
from lwbench.sensor import SensorModel

__all__ = [
    "ScanArrays",
    "read_kitti_bin",
    "read_point_file",
    "read_kitti_poses",
    "read_kitti_calib",
    "read_pose_file",
    "read_ouster_metadata",
    "read_sensor_file",
    "read_xyz",
    "scan_suffix",
    "SCAN_SUFFIXES",
    "DataWarning",
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


NUSCENES_SUFFIX = ".pcd.bin"  # nuScenes LIDAR_TOP: float32 x, y, z, intensity, ring per point
SCAN_SUFFIXES = (NUSCENES_SUFFIX, ".bin", ".pcd", ".ply", ".xyz")


def scan_suffix(path: str | Path) -> str | None:
    """The scan format a file name promises (``.pcd.bin`` before ``.bin``), or None."""
    name = Path(path).name.lower()
    return next((s for s in SCAN_SUFFIXES if name.endswith(s) and len(name) > len(s)), None)


def _ring_column(col: np.ndarray) -> np.ndarray | None:
    """A float column as ring indices, if it is one: whole numbers in [0, 256)."""
    if len(col) == 0 or not np.isfinite(col).all() or col.min() < 0 or col.max() >= 256:
        return None
    if not np.array_equal(col, np.round(col)):
        return None
    return col.astype(np.uint16)


def _read_float32(path: Path) -> np.ndarray:
    size = path.stat().st_size
    if size == 0:
        raise DataFormatError(f"{path}: empty file (0 bytes), no scan in it")
    if size % 4:
        raise DataFormatError(f"{path}: {size} bytes is not a whole number of float32 values")
    return np.fromfile(path, dtype="<f4")


def read_kitti_bin(path: str | Path) -> ScanArrays:
    """A raw float32 scan: KITTI velodyne ``.bin`` (x,y,z,intensity: 16 B/point, or x,y,z:
    12 B/point) or nuScenes ``.pcd.bin`` (x,y,z,intensity,ring: 20 B/point).

    A ``.pcd.bin`` name means nuScenes' 5 columns (read as 4 it gives a wrong point count and
    rings as coordinates). A plain ``.bin`` whose size divides by 20 and whose fifth column is
    all ring indices is read the same way (a renamed nuScenes file). When the size divides by
    both 12 and 16 the layout is ambiguous; the right reading is the one where consecutive
    points (in firing order) are close together -- the wrong one shuffles intensities into
    coordinates and makes neighbours metres apart.
    """
    path = Path(path)
    raw = _read_float32(path)
    n = raw.size
    if path.name.lower().endswith(NUSCENES_SUFFIX):
        if n % 5:
            raise DataFormatError(
                f"{path}: {n * 4} bytes is not N x 20 (nuScenes .pcd.bin: float32 x, y, z, intensity, ring)"
            )
        arr = raw.reshape(-1, 5)
        ring = _ring_column(arr[:, 4])
        if ring is None:
            raise DataFormatError(f"{path}: the fifth column is not a ring index (nuScenes .pcd.bin expected)")
        return ScanArrays(np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3]), ring).finite()
    if n % 5 == 0 and (ring := _ring_column(raw.reshape(-1, 5)[:, 4])) is not None:
        arr = raw.reshape(-1, 5)
        return ScanArrays(np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3]), ring).finite()
    options = [c for c in (4, 3) if n % c == 0]
    if not options:
        raise DataFormatError(
            f"{path}: {n * 4} bytes is neither N x 12 (x,y,z) nor N x 16 (x,y,z,intensity) float32"
        )
    if len(options) == 2:
        steps = {c: _median_step(raw.reshape(-1, c)[:, :3]) for c in options}
        cols = min(steps, key=steps.get)
    else:
        cols = options[0]
    arr = raw.reshape(-1, cols)
    return ScanArrays(np.ascontiguousarray(arr[:, :3]), np.ascontiguousarray(arr[:, 3]) if cols == 4 else None).finite()


def read_xyz(path: str | Path) -> ScanArrays:
    """An ASCII ``.xyz`` scan: one point per line, ``x y z`` (space or comma separated), an
    optional header line and ``#`` comments. A fourth column is read as intensity (the usual
    ``x y z i`` export); more columns (colours, normals) are ignored. A line with another
    number of values is an error naming it, never a silently shorter scan."""
    path = Path(path)
    text = path.read_text(errors="replace")
    lines = [(i + 1, ln.split("#", 1)[0].strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln]
    if not lines:
        raise DataFormatError(f"{path}: no points in this .xyz file")

    def values(line: str) -> list[str]:
        return line.replace(",", " ").split()

    def numeric(line: str) -> bool:
        try:
            [float(v) for v in values(line)]
        except ValueError:
            return False
        return True

    if not numeric(lines[0][1]):
        lines = lines[1:]  # a header line (column names)
    rows = [values(ln) for _, ln in lines]
    width = len(rows[0]) if rows else 0
    bad = next(((i, ln) for (i, ln), r in zip(lines, rows, strict=True) if len(r) != width), None)
    if bad is not None:
        raise DataFormatError(f"{path}: line {bad[0]} has {len(values(bad[1]))} values, the others {width}")
    if width < 3:
        raise DataFormatError(f"{path}: {width} values per line; an .xyz scan needs x y z")
    try:
        arr = np.array(rows, dtype=np.float64)
    except ValueError as exc:
        raise DataFormatError(f"{path}: not numbers: {exc}") from None
    pts = arr[:, :3].astype(np.float32)
    return ScanArrays(pts, arr[:, 3].astype(np.float32) if width == 4 else None).finite()


_PLY_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8,
}  # fmt: skip


def _header_lines(path: Path, end: bytes) -> tuple[list[str], int] | None:
    """The text lines of a PCD/PLY header up to (and including) the line starting with ``end``,
    and the header's length in bytes; None if there is no such line in the first 64 KiB."""
    with open(path, "rb") as fh:
        head = fh.read(65536)
    lines, offset = [], 0
    for raw in head.split(b"\n"):
        offset += len(raw) + 1
        line = raw.decode("ascii", errors="replace").strip()
        lines.append(line)
        if raw.strip().startswith(end):
            return lines, offset
    return None


def _declared(path: Path) -> tuple[int, int | None, int] | None:
    """What a PCD or PLY header promises: point count, body bytes when the body has a fixed
    size (binary, no PLY lists; ``None`` otherwise) and header bytes. None if unparsable."""
    suffix = path.suffix.lower()
    found = _header_lines(path, b"DATA" if suffix == ".pcd" else b"end_header")
    if found is None:
        return None
    lines, header = found
    if suffix == ".pcd":
        kv = {ln.split()[0].upper(): ln.split()[1:] for ln in lines if ln and not ln.startswith("#")}
        try:
            points = int(kv["POINTS"][0]) if "POINTS" in kv else int(kv["WIDTH"][0]) * int(kv["HEIGHT"][0])
            record = sum(int(a) * int(b) for a, b in zip(kv["SIZE"], kv.get("COUNT", ["1"] * len(kv["SIZE"])),
                                                         strict=True))
        except (KeyError, ValueError, IndexError):
            return None
        body = points * record if kv.get("DATA", [""])[0].lower() == "binary" else None
        return points, body, header
    points, body, element, binary = 0, 0, None, any(ln.startswith("format binary") for ln in lines)
    try:
        for ln in lines:
            words = ln.split()
            if words[:1] == ["element"]:
                element = (words[1], int(words[2]))
                if words[1] == "vertex":
                    points = element[1]
            elif words[:1] == ["property"] and element is not None and body is not None:
                if words[1] == "list":
                    body = None
                else:
                    body += element[1] * _PLY_SIZES[words[1]]
    except (IndexError, ValueError, KeyError):
        return None
    return points, (body if binary else None), header


def read_point_file(path: str | Path) -> ScanArrays:
    """A scan file of any format lwbench reads, by its name: ``.bin`` / ``.pcd.bin``
    (:func:`read_kitti_bin`), ``.xyz`` (:func:`read_xyz`), or PCD/PLY through Open3D's tensor
    reader, which keeps intensity, ring and timestamp fields (the legacy reader drops them) and
    reads PCD ``binary_compressed``.

    PCD/PLY files are checked against their header: a body shorter than it declares (a cut
    download) or a point count Open3D does not return is an error, not a shorter scan.
    """
    path = Path(path)
    suffix = scan_suffix(path)
    if suffix in (".bin", NUSCENES_SUFFIX):
        return read_kitti_bin(path)
    if suffix == ".xyz":
        return read_xyz(path)
    if suffix not in (".pcd", ".ply"):
        raise DataFormatError(f"{path}: not a scan file lwbench reads ({', '.join(SCAN_SUFFIXES)})")
    size = path.stat().st_size
    if size == 0:
        raise DataFormatError(f"{path}: empty file (0 bytes), no scan in it")
    declared = _declared(path)
    if declared is None:
        raise DataFormatError(f"{path}: no readable {suffix[1:].upper()} header")
    count, body, header = declared
    if body is not None and size < header + body:
        raise DataFormatError(
            f"{path}: truncated: the header declares {count} points ({body} bytes), the file holds "
            f"{max(size - header, 0)} bytes after it"
        )
    o3d = import_open3d()
    pc = o3d.t.io.read_point_cloud(str(path))
    n_read = pc.point.positions.shape[0] if "positions" in pc.point else 0
    if n_read != count:
        raise DataFormatError(
            f"{path}: the header declares {count} points but Open3D read {n_read} (corrupt or truncated file?)"
        )
    if count == 0:
        return ScanArrays(np.zeros((0, 3), np.float32))
    fields = {k.lower().removeprefix("scalar_"): pc.point[k].numpy() for k in pc.point}
    pts = fields["positions"].astype(np.float32)

    def field(*names: str) -> np.ndarray | None:
        for n in names:
            if n in fields and fields[n].size == len(pts):
                return fields[n].reshape(-1)
        return None

    return ScanArrays(
        pts,
        field("intensity", "intensities", "reflectivity", "remission"),
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
    """A sensor model from an Ouster ``sensor_metadata.json`` (its own beam table). Both the
    legacy flat layout and the nested one of newer firmware (``beam_intrinsics``,
    ``lidar_data_format``, ``config_params``) are read."""
    meta = json.loads(Path(path).read_text())
    beams = meta.get("beam_intrinsics", meta)
    fmt = meta.get("lidar_data_format", meta.get("data_format", {}))
    cols = int(fmt.get("columns_per_frame", 1024))
    mode = str(meta.get("config_params", meta).get("lidar_mode", f"{cols}x10"))
    rate = float(mode.split("x")[1]) if "x" in mode else 10.0
    product = meta.get("sensor_info", meta).get("prod_line", "ouster")
    return SensorModel(
        name=str(product).lower(),
        elevations_deg=tuple(float(a) for a in beams["beam_altitude_angles"]),
        azimuth_step_deg=360.0 / cols,
        min_range=0.3,
        max_range=max_range,
        rate_hz=rate,
    )


def read_sensor_file(path: str | Path) -> SensorModel:
    """A sensor model from a JSON file: lwbench's ``sensor.json`` (what
    :meth:`SensorModel.to_dict` writes) or an Ouster ``sensor_metadata.json``."""
    path = Path(path)
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable JSON sensor file ({exc})") from None
    if not isinstance(meta, dict):
        raise DataFormatError(f"{path}: a sensor file holds a JSON object")
    try:
        if "beam_altitude_angles" in meta.get("beam_intrinsics", meta):
            return read_ouster_metadata(path)
        return SensorModel.from_dict(meta)
    except (KeyError, TypeError, ValueError) as exc:
        raise DataFormatError(
            f"{path}: neither an lwbench sensor.json (name, elevations_deg, azimuth_step_deg, min_range, "
            f"max_range, rate_hz -- or preset) nor an Ouster sensor_metadata.json (beam_altitude_angles): {exc}"
        ) from None


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
