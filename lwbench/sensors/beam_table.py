"""A sensor model's fields read from one scan: beam table, azimuth step, range window.

The rules, in order (the first that holds decides, and :class:`SensorEstimate` says which):

1. **ring field** (PCD ``ring``, nuScenes): per-ring median elevation of the *returns* -- the
   no-return points a driver writes for rays without a return (nuScenes: under 0.1 mm from the
   origin) are left out, else a ring that mostly saw the sky
   takes a no-return point's meaningless elevation (an HDL-32E's rings 22-31 landed at -3.67 deg).
   The azimuth step comes from the points per ring: a driver that writes no-return markers writes one
   point per firing, so the densest ring's count is the firings a turn; without such markers
   the firings missing in the ring's gaps are added back;
2. **ring-major / firing-major order** (:mod:`lwbench.sensors.beam_order`);
3. a **guess** (:mod:`lwbench.sensors.beam_guess`): a preset's table that fits the elevations within a
   stated tolerance, else the beams the elevation histogram resolves, else (no beam structure at
   all) a uniform grid at the data's angular density.

Only 1 and 2 are *exact* (the table is the sensor's); a guess comes with a warning, and the
loaders say so (``sensor_guessed``). The range window: the farthest return (rounded up), and a
minimum range just above the scan's no-return markers (:func:`min_range_above_markers`) -- not
its nearest return, which says only where this scan's nearest object was.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.sensors.beam_guess import METHOD_HISTOGRAM, METHOD_PRESET, METHOD_UNIFORM, guess_beams
from lwbench.sensors.beam_order import Reading, angles, firing_major, firings_per_turn, ring_major, sweep_steps
from lwbench.sensors.specs import DERIVED_RANGE_NOISE_M, MIN_AZIMUTH_STEP_DEG, NO_RETURN_RANGE_M, SENSOR_SPECS

__all__ = [
    "SensorEstimate",
    "estimate_sensor",
    "valid_returns",
    "NO_RETURN_COPIES",
    "min_range_above_markers",
    "coverage_deg",
    "METHOD_RING_FIELD",
    "METHOD_RING_MAJOR",
    "METHOD_FIRING_MAJOR",
    "METHOD_PRESET",
    "METHOD_HISTOGRAM",
    "METHOD_UNIFORM",
    "EXACT_METHODS",
    "OVERRIDE_HINT",
]

METHOD_RING_FIELD = "ring field"
METHOD_RING_MAJOR = "ring-major order"
METHOD_FIRING_MAJOR = "firing-major order"
EXACT_METHODS = frozenset({METHOD_RING_FIELD, METHOD_RING_MAJOR, METHOD_FIRING_MAJOR})
OVERRIDE_HINT = "name the sensor with --dataset-param sensor=<preset or path to sensor.json>"
_MIN_POINTS = 100


@dataclass(frozen=True)
class SensorEstimate:
    """What a scan says about its sensor: ``SensorModel(**fields)``, how it was found (``method``,
    ``rule``: one line naming the rule that decided), counts, warnings, and -- for a guess -- why
    the exact readings did not apply (``notes``)."""

    fields: dict[str, Any]
    method: str
    rule: str
    stats: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def exact(self) -> bool:
        """Whether the table is the sensor's own (ring labels from a field or the order)."""
        return self.method in EXACT_METHODS


#: A point written this many times or more, bit for bit, is a no-return marker, not a return:
#: older nuScenes LIDAR_TOP files write every ray without a return as one fixed point 0.19 m from
#: the sensor (9,220 copies in one scan), far enough out to pass the near test. A real return is
#: at most doubled (a dual-return sensor whose strongest return is also its last).
NO_RETURN_COPIES = 8


def valid_returns(points: np.ndarray, r: np.ndarray | None = None) -> np.ndarray:
    """Which points are returns: not nearer than :data:`NO_RETURN_RANGE_M`, and not an exact copy
    of a point written :data:`NO_RETURN_COPIES` times or more -- the two ways drivers write a ray
    without a return (at the origin or a hair from it; one fixed point, whatever its range)."""
    p = np.asarray(points)
    if r is None:
        r = np.linalg.norm(p.astype(np.float64), axis=1)
    valid = np.asarray(r) >= NO_RETURN_RANGE_M
    if len(p) >= NO_RETURN_COPIES:
        rows = np.ascontiguousarray(p).view(np.dtype((np.void, p.dtype.itemsize * p.shape[1]))).ravel()
        _, inverse, counts = np.unique(rows, return_inverse=True, return_counts=True)
        valid &= counts[inverse.ravel()] < NO_RETURN_COPIES
    return valid


def min_range_above_markers(r: np.ndarray, valid: np.ndarray) -> float:
    """The minimum range a derived model takes: 1 cm beyond the farthest no-return marker (the
    points :func:`valid_returns` leaves out), at least :data:`NO_RETURN_RANGE_M`, never beyond the
    nearest return.

    Not the nearest return itself: that is where the first scan's nearest object happened to be
    (2.2 m on a Pandar64 set), and everything nearer -- a later scan's returns, a decoded point a
    codec put 1 cm nearer -- would then be taken for a no-return marker (VSGP's coverage there
    read 0.959 for what an independent pairing scores 1.000). What the data does show is where
    the markers are: a nuScenes file writes its no-return rays 0.19 m out, so the minimum sits
    just beyond that and a codec's jittered copy of a marker is still no return."""
    r = np.asarray(r, dtype=np.float64)
    markers = r[~valid & np.isfinite(r)]
    floor = NO_RETURN_RANGE_M
    if len(markers):
        floor = max(floor, float(np.ceil(markers.max() * 100) / 100) + 0.01)
    nearest = float(r[valid].min()) if valid.any() else floor
    return min(floor, nearest)


def coverage_deg(az: np.ndarray, step: float) -> int:
    """Degrees of azimuth with returns, in bins wide enough that a coarse sensor fills them."""
    width = max(1.0, 2.0 * step)
    bins = np.unique(np.floor((az % 360.0) / width).astype(np.int64))
    return int(round(min(360.0, bins.size * width)))


def _ring_field(az: np.ndarray, el: np.ndarray, ring: np.ndarray, valid: np.ndarray) -> Reading:
    beams, labels = np.unique(ring, return_inverse=True)
    n = len(beams)
    order = np.flatnonzero(valid)
    sums = np.bincount(labels[order], minlength=n)
    medians = np.full(n, np.nan)
    by_ring = np.argsort(labels[order], kind="stable")
    sorted_el, sorted_lab = el[order][by_ring], labels[order][by_ring]
    bounds = np.searchsorted(sorted_lab, np.arange(n + 1))
    for k in range(n):
        if sums[k]:
            medians[k] = np.median(sorted_el[bounds[k] : bounds[k + 1]])
    stats: dict[str, Any] = {}
    empty = np.flatnonzero(np.isnan(medians))
    if len(empty):
        have = np.flatnonzero(~np.isnan(medians))
        steps = np.diff(medians[have])
        ordered = len(have) > 1 and max(np.mean(steps > 0), np.mean(steps < 0)) >= 0.9
        if ordered:  # ring numbers follow the elevation: interpolate the rings with no return
            medians[empty] = np.interp(empty, have, medians[have])
            stats["rings without a return (interpolated)"] = [int(beams[k]) for k in empty]
        else:
            stats["rings without a return (left out)"] = [int(beams[k]) for k in empty]
            medians = medians[have]
    counts = np.bincount(labels, minlength=n)
    firings = firings_per_turn(az, labels, n, ~valid)
    stats["points per ring (median/max)"] = [int(np.median(counts)), int(counts.max())]
    stats["firings a turn (densest ring)"] = firings
    return Reading(np.sort(medians), 360.0 / max(firings, 1), stats)


def estimate_sensor(
    points: np.ndarray,
    *,
    ring: np.ndarray | None = None,
    rate_hz: float = 10.0,
    name: str = "derived",
    bin_deg: float = 0.02,
    quick: bool = False,
) -> SensorEstimate:
    """Read a sensor model's fields from one scan (rules in the module docstring). ``quick``
    guesses from the histogram alone (no levelling, no presets): enough to tell a later scan of
    another sensor, at a fiftieth of the cost."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1:] != (3,):
        raise ValueError(f"points must have shape (N, 3), got {p.shape}")
    if ring is not None and np.shape(ring) != (len(p),):
        raise ValueError(f"ring must have shape ({len(p)},), got {np.shape(ring)}")
    az, el, r = angles(p)
    valid = valid_returns(p, r)
    if int(valid.sum()) < _MIN_POINTS:
        raise ValueError(f"need at least {_MIN_POINTS} returns to derive a sensor model, got {int(valid.sum())}")
    notes: list[str] = []
    rule = ""
    if ring is not None:
        reading, method = _ring_field(az, el, np.asarray(ring), valid), METHOD_RING_FIELD
        rule = "ring field: per-ring median elevation of the returns; azimuth step from the points per ring"
    else:
        keep = r > 0
        kaz, kel = az[keep], el[keep]
        steps = sweep_steps(kaz)
        reading, method = ring_major(kaz, kel, steps), METHOD_RING_MAJOR
        rule = "ring-major order: one turn of the azimuth per ring"
        if isinstance(reading, str):
            notes.append(reading)
            reading, method = firing_major(kaz, kel, steps), METHOD_FIRING_MAJOR
            rule = "firing-major order: a point's position in a complete firing is its laser"
        if isinstance(reading, str):
            notes.append(reading)
            guess = guess_beams(az[valid], el[valid], r[valid], bin_deg, quick=quick)
            reading, method, rule = guess.reading, guess.method, guess.rule
    rv = r[valid]
    min_range = min_range_above_markers(r, valid)
    max_range = float(np.ceil(rv.max()))
    noise = DERIVED_RANGE_NOISE_M
    if method == METHOD_PRESET:
        spec = reading.stats["preset"]
        # The datasheet's window, widened to the data's: a later scan's far returns are in it.
        min_range = max(min_range, min(SENSOR_SPECS[spec].min_range, float(np.floor(rv.min() * 10) / 10)))
        max_range = max(SENSOR_SPECS[spec].max_range, max_range)
        noise = SENSOR_SPECS[spec].range_noise_m
    # Never finer than a real sensor fires (a shuffled scan's histogram reading gave 0.007 deg,
    # whose grid every metric would then allocate).
    columns = max(1, min(round(360.0 / reading.step), int(360 / MIN_AZIMUTH_STEP_DEG)))
    fields = {
        "name": name,
        "elevations_deg": tuple(float(t) for t in reading.table),
        "azimuth_step_deg": 360.0 / columns,
        "min_range": min_range,
        "max_range": max(max_range, min_range + 1.0),
        "rate_hz": rate_hz,
        "range_noise_m": noise,
    }
    found: list[str] = []
    if method not in EXACT_METHODS:
        found.append(
            f"sensor model guessed ({rule}): {len(reading.table)} beams, azimuth step {360.0 / columns:.4f} deg "
            f"(no ring field, and the point order is neither ring- nor firing-major); if that is not the "
            f"sensor, {OVERRIDE_HINT}"
        )
    coverage = coverage_deg(az[valid], 360.0 / columns)
    if coverage < 324:
        found.append(
            f"the scan covers only {coverage} of 360 deg of azimuth (cropped?): beams it never "
            "sees are missing from the derived table"
        )
    stats = {k: v for k, v in reading.stats.items() if k != "preset"}
    guess_notes = tuple(notes) if method not in EXACT_METHODS else ()
    return SensorEstimate(fields, method, rule, stats, tuple(found), guess_notes)
