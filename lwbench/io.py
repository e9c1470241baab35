"""Reading and writing scans and poses on disk (KITTI layout, PCD/PLY, pose files).

Readers return plain arrays; the dataset classes in :mod:`lwbench.loaders` turn them into
frames. The KITTI writer is what ``lwbench simulate`` and the simulator's cache use, so a
simulated sequence can be fed to any KITTI-reading tool.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench import Frame
from lwbench.deps import import_open3d
from lwbench.errors import DataFormatError, DataWarning
from lwbench.sensor import MIN_AZIMUTH_STEP_DEG, SensorModel

__all__ = [
    "ScanArrays",
    "read_kitti_bin",
    "read_point_file",
    "read_kitti_poses",
    "read_kitti_calib",
    "read_pose_file",
    "read_times",
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


@dataclass(frozen=True)
class _Declared:
    """What a PCD or PLY header promises, to check against the bytes present."""

    points: int
    header: int  # bytes of the header
    body: int | None  # exact body bytes (binary, fixed-size records), else None
    min_body: int  # bytes the declared points need at least (binary), else 0
    ascii: bool  # one text line per point after the header
    compressed: bool = False  # PCD binary_compressed: sizes in the body's first 8 bytes
    record: int = 0  # bytes per point (PCD)


def _declared(path: Path) -> _Declared | None:
    """What a PCD or PLY header promises (None if unparsable)."""
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
        data = kv.get("DATA", [""])[0].lower()
        if points < 0 or record <= 0:
            return None
        body = points * record if data == "binary" else None
        return _Declared(points, header, body, body or 0, data == "ascii", data == "binary_compressed", record)
    points, body, element, binary = 0, 0, None, any(ln.startswith("format binary") for ln in lines)
    min_body, fixed = 0, True  # bytes of the fixed-size elements before the first list
    try:
        for ln in lines:
            words = ln.split()
            if words[:1] == ["element"]:
                element = (words[1], int(words[2]))
                if element[1] < 0:
                    return None
                if words[1] == "vertex":
                    points = element[1]
            elif words[:1] == ["property"] and element is not None:
                if words[1] == "list":
                    body, fixed = None, False
                else:
                    size = element[1] * _PLY_SIZES[words[1]]
                    if body is not None:
                        body += size
                    if fixed:
                        min_body += size
    except (IndexError, ValueError, KeyError):
        return None
    return _Declared(points, header, body if binary else None, min_body if binary else 0, not binary)


def _text_lines(path: Path, start: int) -> int:
    """Non-empty text lines after byte ``start`` (streamed: a file may be large)."""
    count, last = 0, b"\n"
    with open(path, "rb") as fh:
        fh.seek(start)
        while chunk := fh.read(1 << 22):
            count += chunk.count(b"\n") - chunk.count(b"\n\n") - chunk.count(b"\n\r\n")
            last = chunk[-1:]
    return count + (last not in (b"\n", b""))


def _check_declared(path: Path, d: _Declared, size: int) -> None:
    """Refuse a PCD/PLY whose header promises more points than its bytes hold: Open3D then
    returns uninitialised memory (1,000 declared, 10 rows -> 1,000 points up to 3e35), which
    would be scored as a real scan."""
    what = f"the header declares {d.points} points"
    if d.body is not None and size < d.header + d.body:
        raise DataFormatError(
            f"{path}: truncated: {what} ({d.body} bytes), the file holds {max(size - d.header, 0)} bytes after it"
        )
    if d.min_body and size < d.header + d.min_body:
        raise DataFormatError(f"{path}: truncated: {what} ({d.min_body} bytes at least), the file holds "
                              f"{max(size - d.header, 0)} bytes after it")
    if d.compressed:
        with open(path, "rb") as fh:
            fh.seek(d.header)
            head = fh.read(8)
        if len(head) < 8:
            raise DataFormatError(f"{path}: truncated: no compressed body after the header")
        packed, unpacked = struct.unpack("<II", head)
        if unpacked != d.points * d.record or size < d.header + 8 + packed:
            raise DataFormatError(f"{path}: {what} ({d.points * d.record} bytes); the compressed body says "
                                  f"{unpacked} bytes in {packed}, the file holds {max(size - d.header - 8, 0)}")
    if d.ascii and d.points:
        # A text record is at least two bytes per point ("0\n"): a cheap bound first, then lines.
        if size - d.header < 2 * d.points or _text_lines(path, d.header) < d.points:
            raise DataFormatError(f"{path}: truncated: {what}, fewer lines of points follow it")


@contextlib.contextmanager
def _captured_stderr():
    """Collect what C++ code writes to file descriptor 2 (Open3D's errors) instead of letting
    it reach the terminal; yields a list that holds the text, one line, once the block ends."""
    said: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no stderr to redirect
        yield said
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = re.sub(r"\x1b\[[0-9;]*m", "", tmp.read(4000).decode(errors="replace"))
            said.append(" ".join(text.split())[:300])


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
    count = declared.points
    _check_declared(path, declared, size)
    o3d = import_open3d()
    # Open3D prints its own (red) errors for files it cannot read; lwbench says it once, below.
    with _captured_stderr() as said:
        pc = o3d.t.io.read_point_cloud(str(path))
    n_read = pc.point.positions.shape[0] if "positions" in pc.point else 0
    if n_read != count:
        why = f" (Open3D: {said[0]})" if said and said[0] else " (corrupt or truncated file?)"
        raise DataFormatError(f"{path}: the header declares {count} points but Open3D read {n_read}{why}")
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


_MAX_TRANSLATION_M = 1e8  # more than the Earth's radius (ECEF poses)


def _numbers(path: str | Path, lines: list[list[str]], what: str) -> np.ndarray:
    """Rows of numbers, or a :class:`DataFormatError` naming the first line that is not."""
    try:
        return np.array(lines, dtype=np.float64).reshape(len(lines), -1)
    except ValueError:
        for i, ln in enumerate(lines):
            try:
                [float(v) for v in ln]
            except ValueError:
                text = " ".join(ln)[:80]
                raise DataFormatError(f"{path}: line {i + 1} of the {what} is not numbers: {text!r}") from None
        raise DataFormatError(f"{path}: the {what} is not a table of numbers") from None


def _checked_poses(path: str | Path, poses: np.ndarray) -> np.ndarray:
    """Poses a real trajectory can have: finite, rotations orthonormal (to 1 %, as files print
    them), translations within the Earth's radius. A NaN pose or a zero quaternion would
    otherwise end in a traceback, or in metrics that quietly compare against nonsense."""
    bad = ~np.isfinite(poses).all(axis=(1, 2))
    if bad.any():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(bad)[0]) + 1} holds NaN/inf")
    rot = poses[:, :3, :3]
    err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    worst = np.flatnonzero((err > 1e-2) | (det < 0))
    if len(worst):
        raise DataFormatError(f"{path}: pose {int(worst[0]) + 1} is not rigid (orthonormal rotation, det +1)")
    far = np.abs(poses[:, :3, 3]).max(axis=1) > _MAX_TRANSLATION_M
    if far.any():
        first = int(np.flatnonzero(far)[0]) + 1
        raise DataFormatError(f"{path}: pose {first} lies more than {_MAX_TRANSLATION_M:g} m away")
    return poses


def _rows_to_poses(rows: np.ndarray) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    return poses


def _pose_lines(path: str | Path) -> list[list[str]]:
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable pose file ({exc})") from None
    lines = [ln.split() for ln in text.splitlines() if ln.strip() and ln.lstrip()[0] != "#"]
    if not lines:
        raise DataFormatError(f"{path}: empty pose file")
    return lines


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """``poses.txt``: one row of 12 numbers (3x4, row-major) per frame -> ``(N, 4, 4)``."""
    lines = _pose_lines(path)
    width = {len(ln) for ln in lines}
    if width != {12}:
        raise DataFormatError(f"{path}: expected 12 numbers per line, got {sorted(width)}")
    return _checked_poses(path, _rows_to_poses(_numbers(path, lines, "poses")))


def read_kitti_calib(path: str | Path) -> np.ndarray | None:
    """The ``Tr`` (velodyne -> camera) transform of a KITTI odometry ``calib.txt``, if present."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable calib.txt ({exc})") from None
    for line in text.splitlines():
        key, _, values = line.partition(":")
        if key.strip() in ("Tr", "Tr_velo_to_cam"):
            row = _numbers(path, [values.split()], "Tr line")
            if row.size != 12:
                raise DataFormatError(f"{path}: Tr holds {row.size} numbers, not 12")
            t = np.eye(4)
            t[:3, :4] = row.reshape(3, 4)
            return _checked_poses(path, t[None])[0]
    return None


def read_times(path: str | Path, n: int | None = None) -> np.ndarray:
    """``times.txt``: one time stamp (s) per line, finite."""
    lines = _pose_lines(path)
    if {len(ln) for ln in lines} != {1}:
        raise DataFormatError(f"{path}: expected one time stamp per line")
    stamps = _numbers(path, lines, "time stamps")[:, 0]
    if not np.isfinite(stamps).all():
        raise DataFormatError(f"{path}: time stamps hold NaN/inf")
    return stamps


def read_pose_file(path: str | Path) -> tuple[list[str] | None, np.ndarray]:
    """A pose file in any of the layouts real datasets use, detected from its columns:

    - 12 numbers: KITTI (3x4 row-major), one line per frame in order;
    - 8 numbers: TUM (``stamp tx ty tz qx qy qz qw``);
    - a key then 12 numbers: stamped KITTI (key = file stem or time stamp);
    - a key then 7 numbers: TUM with a non-numeric stamp.

    Returns the per-line keys (``None`` for plain KITTI) and ``(N, 4, 4)`` poses, checked
    (finite, rigid; a TUM quaternion of zero length is an error, not a traceback).
    """
    from scipy.spatial.transform import Rotation

    lines = _pose_lines(path)
    width = {len(ln) for ln in lines}
    if len(width) != 1:
        raise DataFormatError(f"{path}: lines have different numbers of fields {sorted(width)}")
    (w,) = width
    if w == 12:
        return None, _checked_poses(path, _rows_to_poses(_numbers(path, lines, "poses")))
    if w not in (8, 13):
        raise DataFormatError(f"{path}: {w} fields per line is neither KITTI (12) nor TUM (8)")
    keys = [ln[0] for ln in lines]
    vals = _numbers(path, [ln[1:] for ln in lines], "poses")
    if w == 13:
        return keys, _checked_poses(path, _rows_to_poses(vals))
    if not np.isfinite(vals).all():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(~np.isfinite(vals).all(1))[0]) + 1} holds NaN/inf")
    norms = np.linalg.norm(vals[:, 3:7], axis=1)
    if (norms < 1e-6).any():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(norms < 1e-6)[0]) + 1} has a zero quaternion")
    poses = np.tile(np.eye(4), (len(vals), 1, 1))
    poses[:, :3, 3] = vals[:, :3]
    poses[:, :3, :3] = Rotation.from_quat(vals[:, 3:7]).as_matrix()
    return keys, _checked_poses(path, poses)


def read_ouster_metadata(path: str | Path, *, max_range: float = 120.0) -> SensorModel:
    """A sensor model from an Ouster ``sensor_metadata.json`` (its own beam table). Both the
    legacy flat layout and the nested one of newer firmware (``beam_intrinsics``,
    ``lidar_data_format``, ``config_params``) are read."""
    meta = json.loads(Path(path).read_text())
    beams = meta.get("beam_intrinsics", meta)
    fmt = meta.get("lidar_data_format", meta.get("data_format", {}))
    cols = fmt.get("columns_per_frame", 1024)
    if isinstance(cols, bool) or not isinstance(cols, int) or not 1 <= cols <= 360 / MIN_AZIMUTH_STEP_DEG:
        raise ValueError(f"columns_per_frame must be a whole number of columns in [1, 36000], got {cols!r}")
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
        inner = meta.get("beam_intrinsics", meta)
        if isinstance(inner, dict) and "beam_altitude_angles" in inner:
            return read_ouster_metadata(path)
        return SensorModel.from_dict(meta)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
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
