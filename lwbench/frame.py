"""The frame: one LiDAR sweep, validated once so that no codec or metric ever sees a bad one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lwbench.errors import InvalidFrameError
from lwbench.sensors.model import SensorModel

__all__ = ["Frame"]


@dataclass(frozen=True, eq=False)
class Frame:
    """One LiDAR sweep in the sensor frame.

    ``points`` is float32 ``(N, 3)``; the optional per-point arrays have length ``N``;
    ``pose`` is the 4x4 sensor->world ground truth when the dataset has one.
    Construction validates, so a codec never sees NaN or a ragged attribute: loaders drop
    non-returns (NaN rows of organized clouds) before they build a frame.
    """

    points: np.ndarray
    sensor: SensorModel
    index: int = 0
    timestamp: float = 0.0
    pose: np.ndarray | None = None
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InvalidFrameError(f"points must have shape (N, 3), got {pts.shape}")
        if not np.issubdtype(pts.dtype, np.floating):
            raise InvalidFrameError(f"points must be floating point, got {pts.dtype}")
        pts = np.ascontiguousarray(pts, dtype=np.float32)
        if not np.isfinite(pts).all():
            bad = int((~np.isfinite(pts).all(axis=1)).sum())
            raise InvalidFrameError(
                f"frame {self.index}: {bad} of {len(pts)} points have NaN/inf coordinates "
                "(drop non-returns before building a Frame)"
            )
        object.__setattr__(self, "points", pts)
        for name in ("intensity", "ring", "time"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.asarray(arr)
                if arr.shape != (len(pts),):
                    raise InvalidFrameError(f"{name} must have shape ({len(pts)},), got {arr.shape}")
                object.__setattr__(self, name, arr)
        if self.pose is not None:
            pose = np.asarray(self.pose, dtype=np.float64)
            if pose.shape != (4, 4) or not np.isfinite(pose).all():
                raise InvalidFrameError(f"pose must be a finite 4x4 matrix, got shape {pose.shape}")
            object.__setattr__(self, "pose", pose)

    def __len__(self) -> int:
        return len(self.points)

    @property
    def raw_bytes(self) -> int:
        """Size of the scan as float32 x,y,z: the reference every ratio is against."""
        return 12 * len(self.points)

    def subset(self, indices: np.ndarray) -> Frame:
        """The frame restricted to ``indices`` (attributes follow)."""
        idx = np.asarray(indices)

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[idx]

        return Frame(
            self.points[idx],
            self.sensor,
            self.index,
            self.timestamp,
            self.pose,
            pick(self.intensity),
            pick(self.ring),
            pick(self.time),
        )
