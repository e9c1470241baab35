"""The data model: frames, declared parameters and the errors every part agrees on."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lwbench.errors import InvalidFrameError, LwbenchError, ParameterError
from lwbench.sensor import SensorModel

__all__ = [
    "Frame",
    "Param",
    "LwbenchError",
    "InvalidFrameError",
    "ParameterError",
    "resolve_params",
]


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


_TYPES: dict[str, type] = {"int": int, "float": float, "str": str, "bool": bool}


@dataclass(frozen=True)
class Param:
    """A parameter a codec or dataset declares, so sweeps, the CLI and ``lwbench list`` know it.

    ``type`` is one of ``int``, ``float``, ``str``, ``bool``. ``low``/``high`` bound numbers
    (inclusive); ``choices`` restricts strings. ``default=None`` means "optional, no value".
    """

    name: str
    type: str
    default: Any
    help: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.type not in _TYPES:
            raise ValueError(f"param {self.name}: type must be one of {sorted(_TYPES)}")

    def parse(self, text: str) -> Any:
        """Convert a command-line string to this parameter's type, then validate."""
        text = text.strip()
        if text.lower() in ("none", "null", ""):
            return self.validate(None)
        try:
            if self.type == "bool":
                if text.lower() in ("1", "true", "yes", "on"):
                    value: Any = True
                elif text.lower() in ("0", "false", "no", "off"):
                    value = False
                else:
                    raise ValueError(text)
            elif self.type == "int":
                value = int(float(text)) if float(text).is_integer() else int(text)
            else:
                value = _TYPES[self.type](text)
        except ValueError:
            raise ParameterError(f"{self.name}: cannot read {text!r} as {self.type}") from None
        return self.validate(value)

    def validate(self, value: Any) -> Any:
        if value is None:
            if self.default is None:
                return None
            raise ParameterError(f"{self.name}: a value is required")
        if self.type == "float" and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
        elif self.type == "int" and isinstance(value, float) and value.is_integer():
            value = int(value)
        expected = _TYPES[self.type]
        if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
            raise ParameterError(f"{self.name}: expected {self.type}, got {value!r}")
        if self.type in ("int", "float"):
            if isinstance(value, float) and not math.isfinite(value):
                raise ParameterError(f"{self.name}: must be finite, got {value}")
            if self.low is not None and value < self.low:
                raise ParameterError(f"{self.name}: {value} is below the minimum {self.low}")
            if self.high is not None and value > self.high:
                raise ParameterError(f"{self.name}: {value} is above the maximum {self.high}")
        if self.choices is not None and value not in self.choices:
            raise ParameterError(f"{self.name}: {value!r} is not one of {list(self.choices)}")
        return value

    def describe(self) -> dict:
        d = {"name": self.name, "type": self.type, "default": self.default, "help": self.help}
        if self.low is not None or self.high is not None:
            d["range"] = [self.low, self.high]
        if self.choices is not None:
            d["choices"] = list(self.choices)
        return d


def resolve_params(owner: str, declared: Sequence[Param], given: Mapping[str, Any]) -> dict:
    """Merge ``given`` over the declared defaults, rejecting unknown names and bad values."""
    by_name = {p.name: p for p in declared}
    unknown = sorted(set(given) - set(by_name))
    if unknown:
        known = ", ".join(sorted(by_name)) or "(none)"
        raise ParameterError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {known}")
    out = {}
    for p in declared:
        raw = given.get(p.name, p.default)
        out[p.name] = p.parse(raw) if isinstance(raw, str) and p.type != "str" else p.validate(raw)
    return out
