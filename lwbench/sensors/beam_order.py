"""Reading the beam table from the order of the points in a file, when there is no ring field.

Most files keep the points in the order the sensor produced them, and the order tells which
ring a point is on:

- **ring-major** (KITTI, ranges images written row by row): each ring's sweep is contiguous, so
  the azimuth turns once per ring; counting turns along the file labels every point;
- **firing-major** (Velodyne and lwbench's simulator drivers: all lasers of one firing, then the
  next): consecutive points share an azimuth within a firing; a point's position in a complete
  firing is its laser.

Each reading is checked before it is trusted (a plausible ring count, similar points per ring,
rings ordered by elevation; for firings, one elevation per position); a reading that does not
hold returns the reason (a string) instead, which :mod:`lwbench.sensors.derive` reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lwbench.sensors.specs import MAX_BEAMS

__all__ = [
    "Reading",
    "angles",
    "sweep_steps",
    "typical_step",
    "segment_medians",
    "ring_major",
    "firing_major",
    "SEAM_TOLERANCE_DEG",
    "firings_per_turn",
]

# A step back along the sweep of up to this many degrees is jitter at a ring's seam (per-laser
# azimuth offsets: ~4 deg on an OS1, a few deg on KITTI); a larger one is a gap *forward*
# (a cropped or occluded part of the turn), e.g. the 280 deg outside a camera's field of view.
SEAM_TOLERANCE_DEG = 10.0
_MOVING_DEG = 1e-3  # steps below this are points of one firing (same azimuth)
_MIN_COMPLETE_FIRINGS = 5


def angles(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    p = np.asarray(points, dtype=np.float64)
    r = np.linalg.norm(p, axis=1)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.degrees(np.arcsin(np.clip(p[:, 2] / np.where(r > 0, r, 1.0), -1.0, 1.0)))
    return az, el, r


def sweep_steps(az: np.ndarray) -> np.ndarray | None:
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


def typical_step(steps: np.ndarray) -> float | None:
    """The firing step from consecutive-point steps: the mean of those near the median, which
    ignores gaps (dropped returns: 2x, 3x the step) and averages out azimuths that a driver
    rounded to 0.01 deg (HDL-32 steps of 0.16 and 0.17 deg for a true 0.166)."""
    fwd = steps[steps > _MOVING_DEG]
    if len(fwd) == 0:
        return None
    med = float(np.median(fwd))
    near = fwd[(fwd > 0.5 * med) & (fwd < 1.5 * med)]
    return float(near.mean()) if len(near) else med


def segment_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Median of ``values`` per label, for labels that are contiguous runs (sorted)."""
    bounds = np.searchsorted(labels, np.arange(n + 1))
    return np.array([np.median(values[bounds[k] : bounds[k + 1]]) for k in range(n)])


@dataclass(frozen=True)
class Reading:
    """A beam table read from a scan: elevations (deg, sorted), azimuth step (deg) and what was
    counted on the way (for ``lwbench inspect``)."""

    table: np.ndarray
    step: float
    stats: dict[str, Any]


def ring_major(az: np.ndarray, el: np.ndarray, steps: np.ndarray | None) -> Reading | str:
    """Rings as the turns of the azimuth along the file (one contiguous sweep per ring)."""
    if steps is None:
        return "ring-major: the azimuth does not change along the file"
    step = typical_step(steps)
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
    medians = segment_medians(el, labels, n)
    dm = np.diff(medians)
    ordered = max(float(np.mean(dm > 0)), float(np.mean(dm < 0)))
    if ordered < 0.9:
        return f"ring-major: {n} rings not ordered by elevation ({ordered:.0%} of neighbours)"
    in_ring = steps[labels[1:] == labels[:-1]]
    step = typical_step(in_ring) or step
    return Reading(
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


def firing_major(az: np.ndarray, el: np.ndarray, steps: np.ndarray | None) -> Reading | str:
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


def _firing_reading(az: np.ndarray, el: np.ndarray, starts: np.ndarray) -> Reading | str:
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
    firing_steps = sweep_steps(firing_az)
    step = None if firing_steps is None else typical_step(firing_steps)
    if step is None:
        return "the firings do not turn"
    columns = 360.0 / step
    if len(sizes) > 1.25 * columns + 2:
        return f"{len(sizes)} firings for {columns:.0f} azimuth steps per turn"
    return Reading(np.sort(table), step, {"firings": len(sizes), "complete firings": len(full)})


def firings_per_turn(az: np.ndarray, labels: np.ndarray, n: int, no_return: np.ndarray | None = None) -> int:
    """Firings a turn, from the densest ring: its point count when the driver writes a point for
    every firing (the ring holds no-return markers), else the firing slots along its sweep -- each
    step between neighbouring returns is a whole number of firing steps (the ring's short steps:
    a gap of dropped returns is several, a second return at one azimuth none)."""
    order = np.lexsort((np.mod(az, 360.0), labels))
    lab, a = labels[order], np.mod(az, 360.0)[order]
    bounds = np.searchsorted(lab, np.arange(n + 1))
    best = 0
    for k in range(n):
        ring = a[bounds[k] : bounds[k + 1]]
        count = len(ring)
        if count < 8:
            continue
        if no_return is not None and no_return[order[bounds[k] : bounds[k + 1]]].any():
            best = max(best, count)
            continue
        d = np.diff(np.r_[ring, ring[0] + 360.0])
        moving = d[d > 1e-6]
        if len(moving) < 8:
            continue
        step = float(np.quantile(moving, 0.2))  # the firing step: most steps are one, gaps are more
        best = max(best, int(np.sum(np.where(d < 0.5 * step, 0, np.round(d / step)))))
    return best
