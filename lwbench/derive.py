"""Deriving a sensor model from one scan, when nothing on disk says what the sensor is.

The beam table is the hard part. A per-point ``ring`` field gives it exactly (per-ring median
elevations). Without one, the elevation histogram is a poor guide on real data: seen from the
sensor origin, a laser's elevation wobbles with range (the laser origins are offset from the
axis), by about as much as the beams are apart -- on KITTI's HDL-64E the per-laser spread is
~0.5 deg for a 0.33 deg spacing, and the histogram finds 81 "beams" instead of 64.

But most files keep the points in the order the sensor produced them, and the order tells which
ring a point is on:

- **ring-major** (KITTI, ranges images written row by row): each ring's sweep is contiguous, so
  the azimuth turns once per ring; counting turns along the file labels every point;
- **firing-major** (Velodyne and lwbench's simulator drivers: all lasers of one firing, then the
  next): consecutive points share an azimuth within a firing; a point's position in a complete
  firing is its laser.

Each reading is checked before it is trusted (a plausible ring count, similar points per ring,
rings ordered by elevation; for firings, one elevation per position) and the histogram is used
only when neither order holds. A histogram table is a guess, so it comes with a warning that
says what was found and how to name the sensor instead. :class:`Derivation` records how the
model was obtained, for ``lwbench inspect``.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lwbench.errors import DataWarning

# More rings than MAX_BEAMS: the order reading is wrong.
from lwbench.sensor import MAX_BEAMS, MIN_AZIMUTH_STEP_DEG, SensorModel

__all__ = [
    "Derivation",
    "derive_sensor",
    "sensor_mismatch",
    "METHOD_RING_FIELD",
    "METHOD_RING_MAJOR",
    "METHOD_FIRING_MAJOR",
    "METHOD_HISTOGRAM",
]

METHOD_RING_FIELD = "ring field"
METHOD_RING_MAJOR = "ring-major order"
METHOD_FIRING_MAJOR = "firing-major order"
METHOD_HISTOGRAM = "elevation histogram"

# A step back along the sweep of up to this many degrees is jitter at a ring's seam (per-laser
# azimuth offsets: ~4 deg on an OS1, a few deg on KITTI); a larger one is a gap *forward*
# (a cropped or occluded part of the turn), e.g. the 280 deg outside a camera's field of view.
SEAM_TOLERANCE_DEG = 10.0
_MOVING_DEG = 1e-3  # steps below this are points of one firing (same azimuth)
_MIN_COMPLETE_FIRINGS = 5
OVERRIDE_HINT = "name the sensor with --dataset-param sensor=<preset or path to sensor.json>"


@dataclass(frozen=True)
class Derivation:
    """A derived sensor model and how it was obtained (method, counts, warnings)."""

    sensor: SensorModel
    method: str
    stats: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()  # why the order readings did not apply (histogram only)

    @property
    def exact(self) -> bool:
        """Whether the beam table comes from ring labels (field or order), not a histogram."""
        return self.method != METHOD_HISTOGRAM

    def describe(self) -> dict[str, Any]:
        s = self.sensor
        info: dict[str, Any] = {
            "method": self.method,
            "beams": s.n_beams,
            "elevation range (deg)": [round(s.elevations_deg[0], 3), round(s.elevations_deg[-1], 3)],
            "azimuth step (deg)": round(s.azimuth_step_deg, 5),
            "columns": s.n_azimuth,
            **self.stats,
        }
        if self.notes:
            info["order readings rejected"] = list(self.notes)
        if self.warnings:
            info["warnings"] = list(self.warnings)
        return info


def _angles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(p, axis=1)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.degrees(np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)))
    return az, el, r


def _sweep_steps(az: np.ndarray) -> np.ndarray | None:
    """Azimuth step from each point to the next, in the direction the sensor turns, in
    ``[-SEAM_TOLERANCE_DEG, 360 - SEAM_TOLERANCE_DEG)``; None when the points do not move."""
    d = (np.diff(az) + 180.0) % 360.0 - 180.0
    moving = np.abs(d) > _MOVING_DEG
    if moving.sum() < 10:
        return None
    direction = -1.0 if np.median(d[moving]) < 0 else 1.0
    s = d * direction
    s[s < -SEAM_TOLERANCE_DEG] += 360.0
    return s


def _typical_step(steps: np.ndarray) -> float | None:
    """The firing step from consecutive-point steps: the mean of those near the median, which
    ignores gaps (dropped returns: 2x, 3x the step) and averages out azimuths that a driver
    rounded to 0.01 deg (HDL-32 steps of 0.16 and 0.17 deg for a true 0.166)."""
    fwd = steps[steps > _MOVING_DEG]
    if len(fwd) == 0:
        return None
    med = float(np.median(fwd))
    near = fwd[(fwd > 0.5 * med) & (fwd < 1.5 * med)]
    return float(near.mean()) if len(near) else med


def _segment_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values`` per label, for labels that are contiguous runs (sorted)."""
    bounds = np.searchsorted(labels, np.arange(n + 1))
    return np.array([np.median(values[bounds[k] : bounds[k + 1]]) for k in range(n)])


@dataclass(frozen=True)
class _Reading:
    table: np.ndarray
    step: float
    stats: dict[str, Any]


def _ring_major(az: np.ndarray, el: np.ndarray, steps: np.ndarray | None) -> _Reading | str:
    """Rings as the turns of the azimuth along the file (one contiguous sweep per ring)."""
    if steps is None:
        return "ring-major: the azimuth does not change along the file"
    step = _typical_step(steps)
    if step is None:
        return "ring-major: the azimuth does not change along the file"
    u = np.concatenate([[0.0], np.cumsum(steps)])
    # A new ring starts when the sweep has turned 360 deg past the first point (half a step of
    # margin against rounding). The running maximum keeps jitter back across a seam in the new ring.
    labels = np.maximum.accumulate(np.floor((u + 0.5 * step) / 360.0).astype(np.int64))
    n = int(labels[-1]) + 1
    while n > 1 and np.sum(labels == n - 1) < max(8, 0.05 * len(labels) / n):
        labels[labels == n - 1] = n - 2  # the last ring's few points past the seam (laser offsets)
        n -= 1
    if n < 2:
        return "ring-major: the points make one turn, not one per ring"
    if n > MAX_BEAMS:
        return f"ring-major: {n} turns of the azimuth is more rings than a LiDAR has"
    counts = np.bincount(labels, minlength=n)
    med_count = float(np.median(counts))
    similar = float(np.mean((counts >= 0.2 * med_count) & (counts <= 5 * med_count)))
    if med_count < 8 or similar < 0.9:
        return f"ring-major: {n} rings with dissimilar point counts (median {med_count:.0f})"
    medians = _segment_medians(el, labels, n)
    dm = np.diff(medians)
    ordered = max(float(np.mean(dm > 0)), float(np.mean(dm < 0)))
    if ordered < 0.9:
        return f"ring-major: {n} rings not ordered by elevation ({ordered:.0%} of neighbours)"
    in_ring = steps[labels[1:] == labels[:-1]]
    step = _typical_step(in_ring) or step
    return _Reading(
        np.sort(medians), step, {"rings": n, "points per ring (median/max)": [int(med_count), int(counts.max())]}
    )


def _firings_by_azimuth(steps: np.ndarray) -> np.ndarray | str:
    """Firing starts where the azimuth moves on (drivers that stamp a firing with one azimuth)."""
    firing_step = float(np.median(steps[steps > _MOVING_DEG]))
    within = np.abs(steps) < 0.25 * firing_step
    if within.mean() < 0.5:
        return "consecutive points rarely share an azimuth"
    return np.flatnonzero(np.concatenate([[True], ~within]))


def _firings_by_elevation(el: np.ndarray) -> np.ndarray | str:
    """Firing starts where the elevation resets (lasers fired in elevation order, as lwbench's
    simulator and row-ordered drivers do; works when per-laser azimuth offsets or motion
    distortion move the azimuth within a firing)."""
    d = np.diff(el)
    up = float(np.mean(d > 0))
    direction = 1.0 if up >= 0.5 else -1.0
    if max(up, 1.0 - up) < 0.65:
        return "the elevation does not sweep one way within firings"
    return np.flatnonzero(np.concatenate([[True], d * direction <= 0]))


def _firing_major(az: np.ndarray, el: np.ndarray, steps: np.ndarray | None) -> _Reading | str:
    """Rings as positions in complete firings: all lasers fire, then the sensor turns a step."""
    if steps is None:
        return "firing-major: the azimuth does not change along the file"
    why = []
    for how, starts in (("shared azimuth", _firings_by_azimuth(steps)), ("elevation resets", None)):
        if starts is None:
            starts = _firings_by_elevation(el)
        reading = starts if isinstance(starts, str) else _firing_reading(az, el, starts)
        if not isinstance(reading, str):
            reading.stats["firings split by"] = how
            return reading
        why.append(reading)
    return "firing-major: " + "; ".join(why)


def _firing_reading(az: np.ndarray, el: np.ndarray, starts: np.ndarray) -> _Reading | str:
    sizes = np.diff(np.append(starts, len(el)))
    # A complete firing has one point per laser, so the laser count is the largest size that
    # recurs (a few complete firings suffice: scans with sky above have only a handful).
    recurring = np.flatnonzero(np.bincount(sizes) >= _MIN_COMPLETE_FIRINGS)
    k = int(recurring.max()) if len(recurring) else 0
    if k < 2:
        return "no firing size recurs"
    if k > MAX_BEAMS or float(np.mean(sizes > k)) > 0.01:
        return f"firings of {k} points, but {int((sizes > k).sum())} larger ones"
    full = starts[sizes == k]
    grid = el[full[:, None] + np.arange(k)[None, :]]
    table = np.median(grid, axis=0)
    spread = np.median(np.abs(grid - table), axis=0)
    gaps = np.diff(np.sort(table))
    if gaps.min() <= 0 or spread.max() >= 0.5 * gaps.min():
        return f"positions in {k}-point firings do not keep one elevation each"
    # The firing's azimuth: its points' mean offset from its first point (wrap-safe).
    offset = (az - np.repeat(az[starts], sizes) + 180.0) % 360.0 - 180.0
    firing_az = az[starts] + np.add.reduceat(offset, starts) / sizes
    firing_steps = _sweep_steps(firing_az)
    step = None if firing_steps is None else _typical_step(firing_steps)
    if step is None:
        return "the firings do not turn"
    columns = 360.0 / step
    if len(sizes) > 1.25 * columns + 2:
        return f"{len(sizes)} firings for {columns:.0f} azimuth steps per turn"
    return _Reading(np.sort(table), step, {"firings": len(sizes), "complete firings": len(full)})


def _ring_field(az: np.ndarray, el: np.ndarray, ring: np.ndarray) -> _Reading:
    order = np.argsort(ring, kind="stable")
    beams = np.unique(ring)
    labels = np.searchsorted(beams, ring[order])
    table = _segment_medians(el[order], labels, len(beams))
    counts = np.bincount(labels, minlength=len(beams))
    densest = np.sort(az[order][labels == np.argmax(counts)])
    step = _typical_step(np.diff(densest)) or 0.2
    return _Reading(table, step, {"points per ring (median/max)": [int(np.median(counts)), int(counts.max())]})


def _histogram(az: np.ndarray, el: np.ndarray, bin_deg: float) -> _Reading:
    from scipy.signal import find_peaks

    # Margins so the outermost beams are interior peaks (find_peaks ignores the edges).
    lo, hi = el.min() - 10 * bin_deg, el.max() + 10 * bin_deg
    hist, edges = np.histogram(el, bins=max(8, int((hi - lo) / bin_deg)), range=(lo, hi))
    smooth = np.convolve(hist, np.ones(3) / 3, mode="same")
    # Real beams are >= ~0.3 deg apart (HDL-64E: 1/3 deg); closer peaks are one beam whose
    # elevation wobbles along the sweep (laser origins are offset from the sensor axis).
    peaks, _ = find_peaks(smooth, height=max(5.0, 0.02 * smooth.max()), distance=int(0.25 / bin_deg))
    if len(peaks) == 0:
        peaks = np.array([int(np.argmax(smooth))])
    table = (edges[peaks] + edges[peaks + 1]) / 2
    labels = np.searchsorted((table[1:] + table[:-1]) / 2, el)
    counts = np.bincount(labels, minlength=len(table))
    densest = np.sort(az[labels == np.argmax(counts)])
    step = _typical_step(np.diff(densest)) or 0.2
    return _Reading(np.sort(table), step, {})


def _coverage_deg(az: np.ndarray, step: float) -> int:
    """Degrees of azimuth with returns, in bins wide enough that a coarse sensor fills them."""
    width = max(1.0, 2.0 * step)
    bins = np.unique(np.floor((az % 360.0) / width).astype(np.int64))
    return int(round(min(360.0, bins.size * width)))


def derive_sensor(
    points: np.ndarray,
    *,
    ring: np.ndarray | None = None,
    rate_hz: float = 10.0,
    name: str = "derived",
    bin_deg: float = 0.02,
    warn: bool = True,
) -> Derivation:
    """Estimate a sensor model from one real scan: the ring field when there is one, else the
    point order (ring-major, then firing-major), else the elevation histogram (with a
    :class:`DataWarning` when ``warn``). The range window is the data's."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) < 100:
        raise ValueError(f"need at least 100 points to derive a sensor model, got {len(p)}")
    if ring is not None and np.shape(ring) != (len(p),):
        raise ValueError(f"ring must have shape ({len(p)},), got {np.shape(ring)}")
    az, el, r = _angles(p)
    ok = r > 0
    if not ok.all():
        p, az, el, r = p[ok], az[ok], el[ok], r[ok]
        ring = None if ring is None else np.asarray(ring)[ok]
    notes: list[str] = []
    if ring is not None:
        reading, method = _ring_field(az, el, np.asarray(ring)), METHOD_RING_FIELD
    else:
        steps = _sweep_steps(az)
        reading = _ring_major(az, el, steps)
        method = METHOD_RING_MAJOR
        if isinstance(reading, str):
            notes.append(reading)
            reading, method = _firing_major(az, el, steps), METHOD_FIRING_MAJOR
        if isinstance(reading, str):
            notes.append(reading)
            reading, method = _histogram(az, el, bin_deg), METHOD_HISTOGRAM
    sensor = SensorModel(
        name=name,
        elevations_deg=tuple(float(t) for t in reading.table),
        # Never finer than a real sensor fires (a shuffled scan's histogram reading gave 0.007 deg,
        # whose grid every metric would then allocate).
        azimuth_step_deg=360.0 / max(1, min(round(360.0 / reading.step), int(360 / MIN_AZIMUTH_STEP_DEG))),
        min_range=float(np.floor(r.min() * 10) / 10),
        max_range=float(np.ceil(r.max())),
        rate_hz=rate_hz,
    )
    found: list[str] = []
    if method == METHOD_HISTOGRAM:
        found.append(
            f"sensor model guessed from the {METHOD_HISTOGRAM}: {sensor.n_beams} beams, azimuth step "
            f"{sensor.azimuth_step_deg:.4f} deg (no ring field, and the point order is neither ring- "
            f"nor firing-major); if that is not the sensor, {OVERRIDE_HINT}"
        )
    coverage = _coverage_deg(az, sensor.azimuth_step_deg)
    if coverage < 324:
        found.append(
            f"the scan covers only {coverage} of 360 deg of azimuth (cropped?): beams it never "
            "sees are missing from the derived table"
        )
    if warn:
        for msg in found:
            warnings.warn(msg, DataWarning, stacklevel=3)
    return Derivation(sensor, method, reading.stats, tuple(found), tuple(notes) if method == METHOD_HISTOGRAM else ())


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
    lo, hi = max(a[0], b[0]), min(a[-1], b[-1])
    na, nb = int(np.sum((a >= lo) & (a <= hi))), int(np.sum((b >= lo) & (b <= hi)))
    if max(na, nb) > (1.5 if exact else 2.0) * min(na, nb) + 2:
        return f"{nb} beams vs {na} between {lo:.1f} and {hi:.1f} deg of elevation"
    ratio = other.sensor.azimuth_step_deg / model.sensor.azimuth_step_deg
    if exact and not 2 / 3 < ratio < 1.5:
        return f"azimuth step {other.sensor.azimuth_step_deg:.4f} vs {model.sensor.azimuth_step_deg:.4f} deg"
    return None
