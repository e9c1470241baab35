"""Raw float32 scans (KITTI velodyne ``.bin``, nuScenes ``.pcd.bin``): the record size decided by
what the bytes hold, never guessed.

A ``.bin`` has no header: the same bytes read as x,y,z (12 bytes a point), x,y,z,intensity (16)
or nuScenes' x,y,z,intensity,ring (20) whenever the size allows several. Reading them with the
wrong record size does not fail -- it shifts columns into each other: KITTI frame 0 written with
intensity 0 and shuffled points read as 12-byte records gave 166,224 "points" with z from -77 to
+77 m. So each reading the size allows is judged by the geometry it yields:

- **hard limits**: coordinates within :data:`~lwbench.sensors.specs.MAX_RANGE_M`, an intensity
  column that is finite and not negative, a ring column of whole numbers in ``[0, 256)``;
- **columns unlike each other**: under a wrong record size every column holds each true column
  in turn (x, then y, then z, then intensity ...), so all columns have *one* distribution -- z
  spans as much as x and y, intensities sit among coordinates. A real scan's columns differ (the
  rotation axis z is narrower than x and y; intensity is another quantity). Measured as the
  largest gap between two columns' quantiles, against the sampling noise of the same quantiles
  between two halves of one column;
- **point order**, when the file has one, only as a check: consecutive points of a scan in firing
  order are centimetres apart under the right reading. It never decides alone (a shuffled file has
  no order, and a plausible order under an implausible geometry is still a misread).

Exactly one plausible reading is taken; none or several is a one-line :class:`DataFormatError`
that names ``--dataset-param fields=xyz|xyzi`` (the ``fields`` argument here).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError
from lwbench.io.scan_arrays import NUSCENES_SUFFIX, ScanArrays
from lwbench.sensors.specs import MAX_BEAMS, MAX_RANGE_M

__all__ = ["read_kitti_bin", "BIN_LAYOUTS", "FIELDS_HINT"]

#: The record layouts a ``.bin`` can hold, by the name ``fields=`` takes: columns, bytes a point.
BIN_LAYOUTS: dict[str, tuple[str, ...]] = {
    "xyz": ("x", "y", "z"),
    "xyzi": ("x", "y", "z", "intensity"),
    "xyzir": ("x", "y", "z", "intensity", "ring"),
}
FIELDS_HINT = "pass --dataset-param fields=xyz|xyzi (xyzir: nuScenes' x,y,z,intensity,ring)"
_BY_WIDTH = {len(v): k for k, v in BIN_LAYOUTS.items()}
_QUANTILES = np.array([0.01, 0.05, 0.1, 0.25, 0.5, 0.75, 0.9, 0.95, 0.99])
_SAMPLE_ROWS = 200_000  # quantiles of a strided sample: a few ms on a 120k-point scan
_MAX_INTENSITY = 1e6  # reflectivity 0-1 (KITTI), 0-255, 16-bit signal (Ouster): all far below
# Columns whose quantiles differ by less than this share of the data's spread are "alike" even
# when the sample is so large that the noise estimate is tiny.
_MIN_DISTINCT = 0.05
_NOISE_FACTOR = 4.0


def _read_float32(path: Path) -> np.ndarray:
    size = path.stat().st_size
    if size == 0:
        raise DataFormatError(f"{path}: empty file (0 bytes), no scan in it")
    if size % 4:
        raise DataFormatError(f"{path}: {size} bytes is not a whole number of float32 values")
    return np.fromfile(path, dtype="<f4")


def _ring_column(col: np.ndarray) -> np.ndarray | None:
    """A float column as ring indices, if it is one: whole numbers in [0, MAX_BEAMS)."""
    if len(col) == 0 or not np.isfinite(col).all() or col.min() < 0 or col.max() >= MAX_BEAMS:
        return None
    if not np.array_equal(col, np.round(col)):
        return None
    return col.astype(np.uint16)


@dataclass(frozen=True)
class _Verdict:
    """How plausible one reading of the bytes is, and why (for the error message)."""

    layout: str
    plausible: bool
    why: str
    step: float  # median distance between consecutive points (m): order evidence


def _quantile_gap(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(np.quantile(a, _QUANTILES) - np.quantile(b, _QUANTILES))))


def _distinctness(cols: np.ndarray) -> tuple[float, float]:
    """The largest quantile gap between two columns and, as its noise floor, the largest gap
    between two random halves of one column -- both in units of the spread of the data (1st to
    99th percentile of the widest column). Random halves, not even and odd rows: in a firing-major
    file of an even number of lasers those are different lasers."""
    q = np.quantile(cols, _QUANTILES[[0, -1]], axis=0)
    scale = float(np.max(q[1] - q[0]))
    if not scale > 0:
        return 0.0, 0.0
    k = cols.shape[1]
    between = max(_quantile_gap(cols[:, a], cols[:, b]) for a in range(k) for b in range(a + 1, k))
    half = np.random.default_rng(0).random(len(cols)) < 0.5
    noise = max(_quantile_gap(cols[half, c], cols[~half, c]) for c in range(k))
    return between / scale, noise / scale


def _median_step(xyz: np.ndarray) -> float:
    sample = xyz[: min(len(xyz), 20000)].astype(np.float64)
    if len(sample) < 2:
        return 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        return float(np.nanmedian(np.linalg.norm(np.diff(sample, axis=0), axis=1)))


def _judge(raw: np.ndarray, layout: str) -> _Verdict:
    """Whether reading ``raw`` with ``layout``'s records yields a plausible scan."""
    width = len(BIN_LAYOUTS[layout])
    rows = raw.reshape(-1, width)
    stride = max(1, len(rows) // _SAMPLE_ROWS)
    sample = rows[::stride].astype(np.float64)
    finite = np.isfinite(sample).all(axis=1)
    step = _median_step(rows[:, :3])

    def verdict(ok: bool, why: str) -> _Verdict:
        return _Verdict(layout, ok, why, step)

    if finite.mean() < 0.5:
        return verdict(False, f"{1 - finite.mean():.0%} of the rows hold NaN/inf")
    sample = sample[finite]
    extent = float(np.abs(sample[:, :3]).max())
    if extent > MAX_RANGE_M:
        return verdict(False, f"coordinates up to {extent:.3g} m")
    if width >= 4:
        inten = sample[:, 3]
        if inten.min() < 0 or inten.max() > _MAX_INTENSITY:
            return verdict(False, f"intensities from {inten.min():.3g} to {inten.max():.3g}")
    if width == 5 and _ring_column(rows[:, 4]) is None:
        return verdict(False, "the fifth column is not a ring index")
    between, noise = _distinctness(sample)
    z = sample[:, 2]
    shape = f"z {z.min():.1f}..{z.max():.1f} m"
    if between <= max(_MIN_DISTINCT, _NOISE_FACTOR * noise):
        return verdict(False, f"every column has the same distribution ({shape}): columns shifted into each other")
    return verdict(True, shape)


def _read_layout(path: Path, raw: np.ndarray, layout: str, drop_non_returns: bool = True) -> ScanArrays:
    width = len(BIN_LAYOUTS[layout])
    arr = raw.reshape(-1, width)
    intensity = np.ascontiguousarray(arr[:, 3]) if width >= 4 else None
    ring = None
    if width == 5:
        ring = _ring_column(arr[:, 4])
        if ring is None:
            raise DataFormatError(f"{path}: the fifth column is not a ring index (nuScenes .pcd.bin expected)")
    scan = ScanArrays(np.ascontiguousarray(arr[:, :3]), intensity, ring)
    return scan.finite() if drop_non_returns else scan


def _size_error(path: Path, n: int, layouts: list[str]) -> DataFormatError:
    what = " nor ".join(f"N x {4 * len(BIN_LAYOUTS[k])} ({','.join(BIN_LAYOUTS[k])})" for k in layouts)
    return DataFormatError(f"{path}: {n * 4} bytes is neither {what} float32")


def read_kitti_bin(path: str | Path, fields: str = "auto", *, drop_non_returns: bool = True) -> ScanArrays:
    """A raw float32 scan: KITTI velodyne ``.bin`` (x,y,z,intensity: 16 B/point, or x,y,z:
    12 B/point) or nuScenes ``.pcd.bin`` (x,y,z,intensity,ring: 20 B/point).

    ``fields`` names the layout (``xyz``, ``xyzi``, ``xyzir``); ``auto`` (the default) takes
    nuScenes' for a ``.pcd.bin`` name and otherwise the one plausible reading of the sizes that
    fit (see the module docstring) -- or raises :class:`DataFormatError` naming ``fields=``.
    ``drop_non_returns=False`` keeps NaN and all-zero rows (to align a per-point sidecar file).
    """
    path = Path(path)
    raw = _read_float32(path)
    n = raw.size
    if fields == "auto" and path.name.lower().endswith(NUSCENES_SUFFIX):
        if n % 5:
            raise DataFormatError(
                f"{path}: {n * 4} bytes is not N x 20 (nuScenes .pcd.bin: float32 x, y, z, intensity, ring)"
            )
        return _read_layout(path, raw, "xyzir", drop_non_returns)
    if fields != "auto":
        if fields not in BIN_LAYOUTS:
            raise DataFormatError(f"{path}: fields={fields!r} is none of {', '.join(BIN_LAYOUTS)}")
        if n % len(BIN_LAYOUTS[fields]):
            raise _size_error(path, n, [fields])
        return _read_layout(path, raw, fields, drop_non_returns)
    sizes = [k for k in BIN_LAYOUTS if n % len(BIN_LAYOUTS[k]) == 0]
    # Five columns only as nuScenes': a fifth column of ring indices.
    sizes = [k for k in sizes if k != "xyzir" or _ring_column(raw.reshape(-1, 5)[:, 4]) is not None]
    if not sizes:
        raise _size_error(path, n, ["xyz", "xyzi"])
    if len(sizes) == 1:
        verdict = _judge(raw, sizes[0])
        if not verdict.plausible and verdict.why.startswith(("coordinates", "NaN")):
            raise DataFormatError(f"{path}: not a float32 scan: read as {sizes[0]}, {verdict.why}")
        return _read_layout(path, raw, sizes[0], drop_non_returns)
    verdicts = [_judge(raw, k) for k in sizes]
    good = [v for v in verdicts if v.plausible]
    said = "; ".join(f"as {v.layout} ({4 * len(BIN_LAYOUTS[v.layout])} B/point): {v.why}" for v in verdicts)
    if len(good) != 1:
        which = "several readings look like a scan" if good else "no reading looks like a scan"
        raise DataFormatError(f"{path}: {n * 4} bytes, {which} -- {said}; {FIELDS_HINT}")
    chosen = good[0]
    others = [v.step for v in verdicts if v is not chosen and v.step > 0]
    if others and chosen.step > 3 * min(others):
        raise DataFormatError(
            f"{path}: {n * 4} bytes: the geometry says {chosen.layout} but the point order says otherwise "
            f"(consecutive points {chosen.step:.2f} m apart vs {min(others):.2f} m) -- {said}; {FIELDS_HINT}"
        )
    return _read_layout(path, raw, chosen.layout, drop_non_returns)
