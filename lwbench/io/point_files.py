"""Scan files with a header or a text layout: PCD and PLY (through Open3D), ASCII ``.xyz``, and
:func:`read_point_file`, which picks the reader from the file name.

A PCD/PLY header promises a point count; a body shorter than that (a cut download) is refused
before Open3D reads it, because Open3D then returns uninitialised memory as points.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.deps import import_open3d
from lwbench.errors import DataFormatError
from lwbench.io.native_stderr import captured_stderr
from lwbench.io.raw_bin import read_kitti_bin
from lwbench.io.scan_arrays import NUSCENES_SUFFIX, SCAN_SUFFIXES, VTK_SUFFIX, ScanArrays, scan_suffix
from lwbench.io.vtk_files import read_vtk

__all__ = ["read_point_file", "read_xyz"]


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
            record = sum(
                int(a) * int(b) for a, b in zip(kv["SIZE"], kv.get("COUNT", ["1"] * len(kv["SIZE"])), strict=True)
            )
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
        raise DataFormatError(
            f"{path}: truncated: {what} ({d.min_body} bytes at least), the file holds "
            f"{max(size - d.header, 0)} bytes after it"
        )
    if d.compressed:
        with open(path, "rb") as fh:
            fh.seek(d.header)
            head = fh.read(8)
        if len(head) < 8:
            raise DataFormatError(f"{path}: truncated: no compressed body after the header")
        packed, unpacked = struct.unpack("<II", head)
        if unpacked != d.points * d.record or size < d.header + 8 + packed:
            raise DataFormatError(
                f"{path}: {what} ({d.points * d.record} bytes); the compressed body says "
                f"{unpacked} bytes in {packed}, the file holds {max(size - d.header - 8, 0)}"
            )
    if d.ascii and d.points:
        # A text record is at least two bytes per point ("0\n"): a cheap bound first, then lines.
        if size - d.header < 2 * d.points or _text_lines(path, d.header) < d.points:
            raise DataFormatError(f"{path}: truncated: {what}, fewer lines of points follow it")


def read_point_file(path: str | Path, *, fields: str = "auto") -> ScanArrays:
    """A scan file of any format lwbench reads, by its name: ``.bin`` / ``.pcd.bin``
    (:func:`read_kitti_bin`, ``fields`` naming its layout), ``.xyz`` (:func:`read_xyz`), ``.vtk``
    polydata (:func:`read_vtk`), or PCD/PLY through Open3D's tensor reader, which keeps
    intensity, ring and timestamp fields (the legacy reader drops them) and reads PCD
    ``binary_compressed``.

    PCD/PLY files are checked against their header: a body shorter than it declares (a cut
    download) or a point count Open3D does not return is an error, not a shorter scan.
    """
    path = Path(path)
    suffix = scan_suffix(path)
    if suffix in (".bin", NUSCENES_SUFFIX):
        return read_kitti_bin(path, fields)
    if suffix == ".xyz":
        return read_xyz(path)
    if suffix == VTK_SUFFIX:
        return read_vtk(path)
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
    with captured_stderr() as said:
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
