"""Deriving a sensor model from one scan, when nothing on disk says what the sensor is -- and
saying how it was derived.

The reading itself is :func:`lwbench.sensors.beam_table.estimate_sensor` (ring field, point order, or a
guess: a preset that fits, the histogram's significant peaks, a uniform grid); this module wraps
it in a :class:`Derivation` (the model, the rule that decided, whether it is ``exact`` or a
guess -- what ``lwbench inspect`` shows and the loaders flag as ``sensor_guessed``), warns when it
is a guess, and checks that a later scan comes from the same sensor (:func:`sensor_mismatch`)
and lies in the model's range window (:func:`outside_range_window`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.errors import DataWarning
from lwbench.sensors.beam_table import (
    EXACT_METHODS,
    METHOD_FIRING_MAJOR,
    METHOD_HISTOGRAM,
    METHOD_PRESET,
    METHOD_RING_FIELD,
    METHOD_RING_MAJOR,
    METHOD_UNIFORM,
    OVERRIDE_HINT,
    estimate_sensor,
    valid_returns,
)
from lwbench.sensors.model import SensorModel

__all__ = [
    "Derivation",
    "DataWarning",
    "derive_sensor",
    "sensor_from_points",
    "sensor_mismatch",
    "outside_range_window",
    "METHOD_RING_FIELD",
    "METHOD_RING_MAJOR",
    "METHOD_FIRING_MAJOR",
    "METHOD_PRESET",
    "METHOD_HISTOGRAM",
    "METHOD_UNIFORM",
    "OVERRIDE_HINT",
]


@dataclass(frozen=True)
class Derivation:
    """A derived sensor model and how it was obtained (method, the rule that decided, counts,
    warnings). ``exact`` when the table is the sensor's own (ring field or point order);
    otherwise the model is a guess (``guessed``), which results scored on it should say."""

    sensor: SensorModel
    method: str
    stats: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()  # why the order readings did not apply (guesses only)
    rule: str = ""

    @property
    def exact(self) -> bool:
        """Whether the beam table comes from ring labels (field or order), not a guess."""
        return self.method in EXACT_METHODS

    @property
    def guessed(self) -> bool:
        return not self.exact

    def describe(self) -> dict[str, Any]:
        s = self.sensor
        info: dict[str, Any] = {
            "method": self.method,
            "rule": self.rule,
            "guessed": self.guessed,
            "beams": s.n_beams,
            "elevation range (deg)": [round(s.elevations_deg[0], 3), round(s.elevations_deg[-1], 3)],
            "azimuth step (deg)": round(s.azimuth_step_deg, 5),
            "columns": s.n_azimuth,
            "range window (m)": [s.min_range, s.max_range],
            **self.stats,
        }
        if self.notes:
            info["order readings rejected"] = list(self.notes)
        if self.warnings:
            info["warnings"] = list(self.warnings)
        return info


def derive_sensor(
    points: np.ndarray,
    *,
    ring: np.ndarray | None = None,
    rate_hz: float = 10.0,
    name: str = "derived",
    bin_deg: float = 0.02,
    warn: bool = True,
    quick: bool = False,
) -> Derivation:
    """Estimate a sensor model from one real scan: the ring field when there is one, else the
    point order (ring-major, then firing-major), else a guess (with a :class:`DataWarning` when
    ``warn``; ``quick``: a guess from the histogram alone, to check a later scan). The range
    window is the data's (no-return points left out)."""
    estimate = estimate_sensor(points, ring=ring, rate_hz=rate_hz, name=name, bin_deg=bin_deg, quick=quick)
    if warn:
        for msg in estimate.warnings:
            warnings.warn(msg, DataWarning, stacklevel=2)
    return Derivation(
        SensorModel(**estimate.fields),
        estimate.method,
        estimate.stats,
        estimate.warnings,
        estimate.notes,
        estimate.rule,
    )


def sensor_from_points(points: np.ndarray, **kwargs: Any) -> SensorModel:
    """The model :func:`derive_sensor` derives (the same as :meth:`SensorModel.from_points`)."""
    return derive_sensor(points, **kwargs).sensor


def outside_range_window(points: np.ndarray, sensor: SensorModel, min_share: float = 0.001) -> str | None:
    """What of a scan's returns lies outside ``sensor``'s range window (no-return markers left out),
    in words, or None when less than ``min_share`` of them does: a model derived from one scan
    knows only that scan's nearest and farthest return, and grid codecs drop what lies beyond
    (a stray return or two a scan is not worth a warning on every frame)."""
    p = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(p, axis=1)
    r = r[valid_returns(p, r)]
    far, near = r[r > sensor.max_range], r[r < sensor.min_range]
    if len(far) + len(near) <= min_share * len(r):
        return None
    said = []
    if len(far):
        said.append(f"{len(far)} returns beyond the max range {sensor.max_range:g} m (up to {far.max():.1f} m)")
    if len(near):
        said.append(f"{len(near)} returns nearer than the min range {sensor.min_range:g} m (from {near.min():.2f} m)")
    return "; ".join(said) or None


def _spacing(table: np.ndarray) -> float:
    return float(np.median(np.diff(table))) if len(table) > 1 else 1.0


def sensor_mismatch(model: Derivation, other: Derivation) -> str | None:
    """Why ``other`` (derived from a later scan) is clearly not the sensor ``model`` was derived
    from, or None when it may be the same one.

    Lenient on purpose, because a scan of the same sensor can lack the beams at the edges of
    the field of view (sky above, a cropped view) and per-ring medians move a little with what a
    scan saw. What no single sensor does: beams well outside the model's field of view, a
    different density of beams where both tables have some, a different azimuth step. A
    histogram table is only a guess, so it is compared with wider margins.
    """
    a, b = np.asarray(model.sensor.elevations_deg), np.asarray(other.sensor.elevations_deg)
    exact = model.exact and other.exact
    margin = 1.5 * _spacing(a) if exact else 2.0
    outside = b[(b < a[0] - margin) | (b > a[-1] + margin)]
    if len(outside) >= 2:
        return (
            f"it has beams at {outside.min():.1f}..{outside.max():.1f} deg, outside the first scan's "
            f"{a[0]:.1f}..{a[-1]:.1f} deg"
        )
    if METHOD_UNIFORM in (model.method, other.method):
        # A uniform grid is no beam table (its rows are the data's density): there are no beams
        # to count against the other's, only the field of view above.
        return None
    lo, hi = max(a[0], b[0]), min(a[-1], b[-1])
    na, nb = int(np.sum((a >= lo) & (a <= hi))), int(np.sum((b >= lo) & (b <= hi)))
    if max(na, nb) > (1.5 if exact else 2.0) * min(na, nb) + 2:
        return f"{nb} beams vs {na} between {lo:.1f} and {hi:.1f} deg of elevation"
    ratio = other.sensor.azimuth_step_deg / model.sensor.azimuth_step_deg
    if exact and not 2 / 3 < ratio < 1.5:
        return f"azimuth step {other.sensor.azimuth_step_deg:.4f} vs {model.sensor.azimuth_step_deg:.4f} deg"
    return None
