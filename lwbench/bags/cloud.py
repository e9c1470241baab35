"""``sensor_msgs/PointCloud2`` <-> arrays, by field name, with numpy alone.

Drivers lay points out differently (Velodyne: x y z intensity ring time; Ouster: x y z t
intensity reflectivity ring ambient range, padded; Hesai: ... timestamp as float64), so fields
are found by *name* and read through one structured dtype built from the message's own
offsets, point step and row step (rows may be padded). Organized clouds mark non-returns with
NaN; :meth:`ScanArrays.finite` drops them, as the file loaders do.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from lwbench.errors import DataFormatError
from lwbench.io import ScanArrays

__all__ = ["FIELD_NAMES", "cloud_arrays", "cloud_layout"]

_DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
# The names each attribute goes by in the drivers lwbench has met; the first present wins.
FIELD_NAMES = {
    "intensity": ("intensity", "intensities", "i", "reflectivity"),
    "ring": ("ring", "channel", "laser_id"),
    "time": ("time", "t", "timestamp", "offset_time"),
}


def _structured(fields: list[Any], point_step: int, bigendian: bool, where: str) -> np.dtype:
    endian = ">" if bigendian else "<"
    names, formats, offsets = [], [], []
    for f in fields:
        code = _DATATYPES.get(int(f.datatype))
        if code is None:
            raise DataFormatError(f"{where}: field {f.name!r} has unknown PointField datatype {f.datatype}")
        count = max(int(f.count), 1)
        size = np.dtype(code).itemsize * count
        if f.offset < 0 or f.offset + size > point_step:
            raise DataFormatError(
                f"{where}: field {f.name!r} (offset {f.offset}) does not fit a {point_step}-byte point"
            )
        if f.name in names:
            continue  # a repeated name (some drivers pad with "" fields): the first is the field
        names.append(f.name)
        formats.append((endian + code, (count,)) if count > 1 else endian + code)
        offsets.append(int(f.offset))
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def cloud_arrays(msg: Any, where: str = "PointCloud2") -> ScanArrays:
    """x, y, z (required), intensity, ring and per-point time (when present) of one message."""
    n = int(msg.width) * int(msg.height)
    step, row_step = int(msg.point_step), int(msg.row_step)
    if n == 0:
        return ScanArrays(np.zeros((0, 3), np.float32))
    if step <= 0 or row_step < step * int(msg.width):
        raise DataFormatError(f"{where}: point_step {step} / row_step {row_step} do not fit width {msg.width}")
    dtype = _structured(list(msg.fields), step, bool(msg.is_bigendian), where)
    missing = [c for c in "xyz" if c not in dtype.names]
    if missing:
        raise DataFormatError(f"{where}: no {', '.join(missing)} field (fields: {', '.join(dtype.names)})")
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if len(data) < row_step * int(msg.height):
        raise DataFormatError(f"{where}: {len(data)} data bytes for {msg.height} rows of {row_step}")
    rows = data[: row_step * int(msg.height)].reshape(int(msg.height), row_step)[:, : step * int(msg.width)]
    arr = np.frombuffer(np.ascontiguousarray(rows).tobytes(), dtype=dtype, count=n)
    points = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float32)

    def pick(what: str, kind: type) -> np.ndarray | None:
        for name in FIELD_NAMES[what]:
            if name in dtype.names and arr[name].ndim == 1:
                return arr[name].astype(kind)
        return None

    ring = pick("ring", np.int64)
    if ring is not None and (ring.min(initial=0) < 0 or ring.max(initial=0) > 0xFFFF):
        ring = None  # not a beam index after all
    ring16 = None if ring is None else ring.astype(np.uint16)
    return ScanArrays(points, pick("intensity", np.float32), ring16, pick("time", np.float64)).finite()


def cloud_layout(points: np.ndarray, intensity: np.ndarray | None = None, ring: np.ndarray | None = None,
                 time: np.ndarray | None = None) -> tuple[list[tuple[str, int, int]], int, bytes]:
    """Fields ``(name, offset, datatype)``, point step and data bytes for a cloud to write:
    float32 x y z [intensity] [time], then uint16 ring -- the layout Velodyne drivers publish."""
    cols: list[tuple[str, np.ndarray, str, int]] = [
        ("x", points[:, 0], "<f4", 7), ("y", points[:, 1], "<f4", 7), ("z", points[:, 2], "<f4", 7)]
    if intensity is not None:
        cols.append(("intensity", intensity, "<f4", 7))
    if time is not None:
        cols.append(("time", time, "<f4", 7))
    if ring is not None:
        cols.append(("ring", ring, "<u2", 4))
    offsets, off = [], 0
    for _, _, code, _ in cols:
        offsets.append(off)
        off += np.dtype(code).itemsize
    step = (off + 3) // 4 * 4
    dtype = np.dtype({"names": [c[0] for c in cols], "formats": [c[2] for c in cols], "offsets": offsets,
                      "itemsize": step})
    rec = np.zeros(len(points), dtype=dtype)
    for name, values, _, _ in cols:
        rec[name] = values
    fields = [(c[0], o, c[3]) for c, o in zip(cols, offsets, strict=True)]
    return fields, step, rec.tobytes()
