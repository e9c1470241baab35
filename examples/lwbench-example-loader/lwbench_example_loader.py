"""An example third-party lwbench loader: ``csvscans``, a folder of ``.csv`` scans.

Each scan is a text file of one point a line, ``x,y,z`` in metres (``000000.csv``,
``000001.csv``, ... in name order). Nothing on disk says what the sensor is, so the loader does
what lwbench's own loaders do with such data, through the public API only:

- :func:`lwbench.derive_sensor` derives the sensor model from the first scan: from the point
  order when the scan is in ring-major or firing-major order (then the model is *exact*), else
  as a guess (a preset that fits, the elevation histogram, a uniform grid), with a
  :class:`lwbench.DataWarning` that says so;
- :attr:`lwbench.Dataset.sensor_guessed` answers the :class:`lwbench.Derivation`'s ``guessed``:
  every result row scored on this dataset then carries the board's ``sensor guessed`` flag,
  because the range metrics stand on that beam table;
- :func:`lwbench.outside_range_window` warns when a later scan has returns outside the range
  window of the model derived from the first one (grid codecs drop them).

A model derived from data is a fallback: when the sensor is known, a loader should take it as a
parameter (a preset name, :func:`lwbench.get_sensor`) and then it is not a guess.
"""

from __future__ import annotations

import warnings
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lwbench import (
    DataFormatError,
    Dataset,
    DataWarning,
    Derivation,
    Frame,
    Param,
    SensorModel,
    derive_sensor,
    hookimpl,
    outside_range_window,
)

__version__ = "0.1.0"
__all__ = ["CsvScans", "read_csv_scan", "write_csv_scan"]

SUFFIX = ".csv"


def read_csv_scan(path: Path) -> np.ndarray:
    """One scan: float32 ``(N, 3)``; rows that are not finite are left out (no return)."""
    try:
        points = np.loadtxt(path, delimiter=",", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise DataFormatError(f"csvscans: {path.name}: not x,y,z rows ({exc})") from None
    if points.size == 0:
        return np.zeros((0, 3), np.float32)
    if points.shape[1] != 3:
        raise DataFormatError(f"csvscans: {path.name}: {points.shape[1]} columns, expected x,y,z")
    return points[np.isfinite(points).all(axis=1)].astype(np.float32)


def write_csv_scan(path: Path, points: np.ndarray) -> None:
    """Write a scan in this format (tests, examples)."""
    np.savetxt(path, np.asarray(points, dtype=np.float32), delimiter=",", fmt="%.6f")


class CsvScans(Dataset):
    """A folder of ``x,y,z`` text scans without a sensor description (see the module docstring)."""

    name = "csvscans"
    description = "folder of .csv scans (x,y,z a line); sensor model derived from the first scan"
    params = (
        Param("path", "str", None, "folder of .csv scans"),
        Param("rate_hz", "float", 10.0, "frame rate of the scans", low=0.01),
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if not self.config["path"]:
            raise DataFormatError("csvscans: the path parameter is required")
        self.folder = Path(self.config["path"])
        if not self.folder.is_dir():
            raise DataFormatError(f"csvscans: {self.folder} is not a folder")
        self.files = sorted(p for p in self.folder.iterdir() if p.suffix == SUFFIX and p.is_file())
        if not self.files:
            raise DataFormatError(f"csvscans: no {SUFFIX} scans in {self.folder}")

    def __len__(self) -> int:
        return len(self.files)

    @property
    def has_poses(self) -> bool:
        return False

    @cached_property
    def derivation(self) -> Derivation:
        """The sensor model derived from the first scan, and how (``method``, ``rule``,
        ``guessed``). A guess warns (:class:`lwbench.DataWarning`), once, here."""
        points = read_csv_scan(self.files[0])
        if len(points) < 100:
            raise DataFormatError(f"csvscans: {self.files[0].name}: {len(points)} points, too few to derive a sensor")
        try:
            return derive_sensor(points, rate_hz=self.config["rate_hz"], name="derived")
        except ValueError as exc:  # no plausible sensor fits the scan
            raise DataFormatError(f"csvscans: {self.files[0].name}: no sensor model fits ({exc})") from None

    @property
    def sensor(self) -> SensorModel:
        return self.derivation.sensor

    @property
    def sensor_guessed(self) -> bool:
        """Whether the model is a guess: every row scored on it says so (``sensor guessed``)."""
        return self.derivation.guessed

    def frame(self, index: int) -> Frame:
        points = read_csv_scan(self.files[index])
        if index > 0:
            outside = outside_range_window(points, self.sensor)
            if outside is not None:
                warnings.warn(f"csvscans: {self.files[index].name}: {outside}, outside the range window of the "
                              f"model derived from {self.files[0].name}", DataWarning, stacklevel=2)
        return Frame(points, self.sensor, index=index, timestamp=index / self.sensor.rate_hz)

    def frame_origin(self, index: int) -> dict[str, Any]:
        return {"name": self.files[index].stem}

    def source_info(self) -> dict[str, Any]:
        """What ``lwbench inspect`` shows: how the sensor model was obtained."""
        return {"layout": f"folder of {SUFFIX} scans", "sensor source": f"derived from {self.files[0].name}",
                "sensor guessed": self.sensor_guessed, "derived sensor": self.derivation.describe()}

    @classmethod
    def sniff(cls, path: Path) -> bool:
        try:
            return path.is_dir() and any(p.suffix == SUFFIX for p in path.iterdir())
        except OSError:
            return False


@hookimpl
def lwbench_datasets() -> list[type[Dataset]]:
    return [CsvScans]
