"""What every scan reader returns (:class:`ScanArrays`) and which file names are scans."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ScanArrays", "scan_suffix", "SCAN_SUFFIXES", "NUSCENES_SUFFIX", "VTK_SUFFIX"]

NUSCENES_SUFFIX = ".pcd.bin"  # nuScenes LIDAR_TOP: float32 x, y, z, intensity, ring per point
VTK_SUFFIX = ".vtk"  # legacy VTK polydata, as libpointmatcher writes scans
SCAN_SUFFIXES = (NUSCENES_SUFFIX, ".bin", ".pcd", ".ply", ".xyz", VTK_SUFFIX)


def scan_suffix(path: str | Path) -> str | None:
    """The scan format a file name promises (``.pcd.bin`` before ``.bin``), or None."""
    name = Path(path).name.lower()
    return next((s for s in SCAN_SUFFIXES if name.endswith(s) and len(name) > len(s)), None)


@dataclass
class ScanArrays:
    """One scan as read from disk: points (float32 ``(N, 3)``) and the per-point fields found."""

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
