"""Guessing a beam table from the elevations alone (no ring field, no usable point order).

Downsampled keyframes, deskewed or filtered scans keep only the points' directions. Seen from
the sensor origin a laser's elevation wobbles with range (its origin is offset from the axis: on
KITTI's HDL-64E by as much as the beams are apart), so the histogram's peaks are not the beams:
it found 81 "beams" on a shuffled KITTI scan, 105 on an OS1-64. So the elevations are first
put back into the sensor's frame where the scan's frame is tilted against it or its lasers sit
above its origin (:func:`level`), then three rules, the first that holds decides:

1. **a preset fits** (:data:`~lwbench.sensors.specs.SENSOR_SPECS`): after a common elevation
   offset of at most :data:`MAX_OFFSET_DEG` (mounting, calibration) and per-beam moves of at most
   :data:`MAX_BEAM_SHIFT` of the local spacing (a unit's own calibration), the returns
   concentrate on the preset's beams -- their RMS distance to the nearest beam at most
   :data:`MAX_SPREAD` spacings (uniform elevations give 0.29), at most :data:`MAX_OUTSIDE` of
   them outside the table, and at least :data:`MIN_OCCUPIED` of the beams in the scan's span
   with returns at their centre (a finer table, with beams between the data's, does not fit).
   Of the presets that fit, the one with the fewest beams is taken; two that fit as well with as
   many beams are no snap. The snapped
   table is the preset's, moved to where this scan's returns are; all its beams are kept, also
   those the scan never saw (sky);
2. **the histogram's significant peaks**: a peak counts when it stands out of its valley by
   three times the counting noise and by a quarter of its height; peaks closer than the data's
   own peak width are one, and so are neighbouring peaks whose returns rarely share an azimuth
   (one beam, its elevation drifting with range). The count is bounded by what the elevation
   resolution of the data supports -- fewer beams than the sensor has when its beams overlap;
3. **no beam table** (no significant peak, more than :data:`~lwbench.sensors.specs.MAX_BEAMS`, or
   peaks that hold the returns no better than uniform elevations would, :data:`MAX_TABLE_SPREAD`:
   a rotating 2-D laser, a scanner with a continuous vertical pattern, beams blurred together): a
   uniform grid as fine as the data is dense -- about one return a cell, at most ``MAX_BEAMS`` rows.

All three are guesses: the estimate (:mod:`lwbench.sensors.beam_table`) is not ``exact`` and the
loaders flag the dataset (``sensor_guessed``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lwbench.sensors.beam_order import Reading, firings_per_turn
from lwbench.sensors.specs import MAX_BEAMS, MAX_RAYS, MIN_AZIMUTH_STEP_DEG, SENSOR_SPECS

__all__ = [
    "Guess",
    "METHOD_PRESET",
    "METHOD_HISTOGRAM",
    "METHOD_UNIFORM",
    "guess_beams",
    "MAX_OFFSET_DEG",
    "MAX_BEAM_SHIFT",
    "MAX_SPREAD",
    "MAX_OUTSIDE",
    "MIN_OCCUPIED",
]

METHOD_PRESET = "preset table fitted to the elevations"
METHOD_HISTOGRAM = "elevation histogram"
METHOD_UNIFORM = "uniform grid (no beam structure)"
MAX_OFFSET_DEG = 1.5  # common offset of a preset's table (mount pitch, a unit's calibration)
_OFFSET_STEP_DEG = 0.02
MAX_BEAM_SHIFT = 0.35  # per-beam move, in local beam spacings
MAX_SPREAD = 0.2  # RMS distance of the returns to the nearest beam, in spacings (uniform: 0.289)
MAX_OUTSIDE = 0.02  # share of returns more than half a spacing outside the table
MIN_OCCUPIED = 0.9  # share of the beams in the scan's span that hold returns at their centre
#: RMS distance of the returns to the nearest histogram peak (in spacings) above which the peaks
#: are no beam table: uniform elevations give 0.289. A rotating 2-D laser whose lines were thinned
#: shows bumps in a smooth histogram -- 51, 92 and 98 "beams" on three consecutive generated scans
#: of one scanner (spread 0.285-0.30), so the second was refused as another sensor -- and so does
#: a 64-beam scan whose beams blur into each other (10 "beams", 0.293). A table of them misleads
#: every metric that reads it; a uniform grid at the data's density does not. Real beams sit
#: well below: KITTI shuffled 0.252 (67 peaks for 64 lasers whose elevations wander with range),
#: voxel keyframes 0.20-0.26.
MAX_TABLE_SPREAD = 0.27
_MIN_CORE_SHARE = 0.6  # of a beam's cell, the share within a quarter spacing of it (uniform: 0.5)
MAX_TILT_DEG = 2.0  # tilt of the scan's frame against the sensor's axis that level() undoes
MAX_LASER_HEIGHT_M = 0.3  # height of the lasers' origin over the frame's that level() undoes
_MIN_SHARPENING = 1.15
_FINE_BIN_DEG = 0.01
_MIN_PEAK_SIGMAS = 3.0
_MIN_MEAN_BIN_COUNT = 20.0
_MIN_SHARED_AZIMUTHS = 0.7  # of the 1-deg azimuth bins of the sparser of two neighbouring peaks
_MIN_PEAK_CONTRAST = 0.25


@dataclass(frozen=True)
class Guess:
    reading: Reading
    method: str
    rule: str


def _sharpness(el: np.ndarray) -> float:
    """How peaked the elevation histogram is (sum of squared bin shares, 0.02 deg bins)."""
    hist = np.bincount(np.floor((el - el.min()) / 0.02).astype(np.int64)).astype(np.float64)
    return float(np.sum(hist**2) / len(el) ** 2)


def level(az: np.ndarray, el: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
    """The elevations as the sensor saw them, when the scan's frame is not the sensor's: a frame
    tilted against the sensor's axis (a deskewed or levelled scan) moves each beam up and down
    with azimuth -- a 0.2 deg tilt splits every beam of an OS1-64 in two histogram peaks -- and
    lasers whose origin sits ``h`` above the frame's make each beam's elevation drift with range
    (KITTI: h ~0.2 m). Tilt (up to :data:`MAX_TILT_DEG`) and ``h`` (up to :data:`MAX_LASER_HEIGHT_M`)
    are the ones that make the histogram sharpest; they are kept only if they sharpen it by
    :data:`_MIN_SHARPENING` at least, so a scan in its sensor's frame is left as it is."""
    a = np.radians(az)
    cos_a, sin_a = np.cos(a), np.sin(a)
    rho = r * np.cos(np.radians(el))
    z = r * np.sin(np.radians(el))
    base = _sharpness(el)
    best = (base, 0.0, 0.0, 0.0)

    def elevations(tx: float, ty: float, h: float) -> np.ndarray:
        return np.degrees(np.arctan2(z - h, rho)) - tx * cos_a - ty * sin_a

    for _ in range(2):
        _, tx, ty, h = best
        for step in (0.5, 0.1, 0.02):  # tilt: coarse to fine around the best so far
            grid = np.arange(-4, 5) * step
            trials = [
                (tx + dx, ty + dy)
                for dx in grid
                for dy in grid
                if abs(tx + dx) <= MAX_TILT_DEG and abs(ty + dy) <= MAX_TILT_DEG
            ]
            e0 = np.degrees(np.arctan2(z - h, rho))
            scores = [(_sharpness(e0 - x * cos_a - y * sin_a), x, y) for x, y in trials]
            score, tx, ty = max(scores)
            if score > best[0]:
                best = (score, tx, ty, h)
        _, tx, ty, h = best
        heights = np.arange(-MAX_LASER_HEIGHT_M, MAX_LASER_HEIGHT_M + 1e-9, 0.025)
        score, h = max((_sharpness(elevations(tx, ty, hh)), hh) for hh in heights)
        if score > best[0]:
            best = (score, tx, ty, h)
    score, tx, ty, h = best
    if score < _MIN_SHARPENING * base:
        return el, {}
    return elevations(tx, ty, h), {
        "tilt (deg)": [round(float(tx), 2), round(float(ty), 2)],
        "laser height (m)": round(float(h), 3),
    }


def _fractional_index(x: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Elevation as a fractional beam index, linear in the table (edge spacing outside it)."""
    u = np.interp(x, table, np.arange(len(table), dtype=np.float64))
    lo_gap, hi_gap = table[1] - table[0], table[-1] - table[-2]
    u = np.where(x < table[0], (x - table[0]) / lo_gap, u)
    return np.where(x > table[-1], len(table) - 1 + (x - table[-1]) / hi_gap, u)


@dataclass(frozen=True)
class _Fit:
    preset: str
    table: np.ndarray
    offset: float
    spread: float
    outside: float
    occupied: float
    in_span: int

    @property
    def fits(self) -> bool:
        return (
            self.spread <= MAX_SPREAD
            and self.outside <= MAX_OUTSIDE
            and self.occupied >= MIN_OCCUPIED
            and self.in_span >= len(self.table) / 2
        )


def _fit_preset(name: str, centres: np.ndarray, hist: np.ndarray) -> _Fit:
    table = np.sort(np.asarray(SENSOR_SPECS[name].elevations_deg, dtype=np.float64))
    total = hist.sum()
    offsets = np.arange(-MAX_OFFSET_DEG, MAX_OFFSET_DEG + 1e-9, _OFFSET_STEP_DEG)
    u = _fractional_index(centres[None, :] - offsets[:, None], table)
    score = np.where((u < -0.5) | (u > len(table) - 0.5), -1.0, np.cos(2 * np.pi * (u - np.round(u))))
    offset = float(offsets[int(np.argmax(score @ hist))])
    moved = table + offset
    gaps = np.diff(table)
    # A beam moves at most MAX_BEAM_SHIFT of its nearer neighbour's gap: beams never cross.
    spacing = np.minimum(np.r_[gaps[:1], gaps], np.r_[gaps, gaps[-1:]]) if len(table) > 1 else np.ones(1)
    for _ in range(2):  # move each beam to its returns' mean, within MAX_BEAM_SHIFT spacings
        u = _fractional_index(centres, moved)
        k = np.clip(np.round(u).astype(np.int64), 0, len(table) - 1)
        near = np.abs(u - k) < 0.5
        w = np.bincount(k[near], weights=hist[near], minlength=len(table))
        mean = np.bincount(k[near], weights=(hist * (centres - moved[k]))[near], minlength=len(table))
        shift = np.where(w > 0, mean / np.maximum(w, 1e-12), 0.0)
        moved = (
            table
            + offset
            + np.clip(shift + (moved - table - offset), -MAX_BEAM_SHIFT * spacing, MAX_BEAM_SHIFT * spacing)
        )
    u = _fractional_index(centres, moved)
    rho = u - np.round(u)
    inside = (u >= -0.5) & (u <= len(table) - 0.5)
    spread = float(np.sqrt(np.sum(hist[inside] * rho[inside] ** 2) / max(hist[inside].sum(), 1e-12)))
    k = np.clip(np.round(u).astype(np.int64), 0, len(table) - 1)
    cell = np.bincount(k[inside], weights=hist[inside], minlength=len(table))
    central = inside & (np.abs(rho) < 0.25)
    core = np.bincount(k[central], weights=hist[central], minlength=len(table))
    # A beam is there when its cell holds returns and they sit at its centre (a beam that is not
    # there holds only the tails of its neighbours'; uniform elevations put half at the centre).
    seen = np.flatnonzero(cell > 0.001 * total)
    lo, hi = (int(seen.min()), int(seen.max())) if len(seen) else (0, -1)
    there = (cell > 0.0002 * total) & (core >= _MIN_CORE_SHARE * cell)
    occupied = float(np.mean(there[lo : hi + 1])) if hi >= lo else 0.0
    return _Fit(name, moved, offset, spread, float(hist[~inside].sum() / total), occupied, hi - lo + 1)


def _snap(el: np.ndarray) -> tuple[_Fit | None, list[_Fit]]:
    edges = np.arange(el.min() - 2 * _FINE_BIN_DEG, el.max() + 3 * _FINE_BIN_DEG, _FINE_BIN_DEG)
    hist, edges = np.histogram(el, bins=edges)
    centres = (edges[:-1] + edges[1:]) / 2
    keep = hist > 0
    centres, hist = centres[keep], hist[keep].astype(np.float64)
    fits = sorted((_fit_preset(name, centres, hist) for name in SENSOR_SPECS), key=lambda f: f.spread)
    # The coarsest table that fits: a finer one also "fits" returns blended between beams (voxel
    # averages), and a beam the data does not need is a beam the sensor need not have.
    good = sorted((f for f in fits if f.fits), key=lambda f: (len(f.table), f.spread))
    if not good:
        return None, fits
    best = good[0]
    rivals = [f for f in good[1:] if len(f.table) == len(best.table) and f.spread < 1.1 * best.spread]
    return (None if rivals else best), fits


def _peaks(el: np.ndarray, bin_deg: float) -> tuple[np.ndarray, float]:
    """Significant peaks of the elevation histogram (deg) and the median peak width (deg)."""
    from scipy.signal import find_peaks, peak_widths

    # Bins that hold some 20 returns on average: a sparse scan's "peaks" of two or three points
    # are noise, not beams.
    bin_deg = max(bin_deg, _MIN_MEAN_BIN_COUNT * float(np.ptp(el)) / len(el))
    lo, hi = el.min() - 10 * bin_deg, el.max() + 10 * bin_deg
    hist, edges = np.histogram(el, bins=max(8, int((hi - lo) / bin_deg)), range=(lo, hi))
    smooth = np.convolve(hist, np.ones(3) / 3, mode="same")
    centres = (edges[:-1] + edges[1:]) / 2
    distance = max(1, int(0.25 / bin_deg))
    for _ in range(4):  # merge peaks closer than the data resolves, until the count is stable
        peaks, props = find_peaks(smooth, distance=distance, prominence=0.0)
        height = smooth[peaks]
        noise = np.sqrt(np.maximum(height, 1.0) / 3.0)  # Poisson noise of a 3-bin mean
        strong = (props["prominences"] >= _MIN_PEAK_SIGMAS * noise) & (
            props["prominences"] >= _MIN_PEAK_CONTRAST * height
        )
        peaks = peaks[strong]
        if len(peaks) == 0:
            return np.zeros(0), 0.0
        width = float(np.median(peak_widths(smooth, peaks, rel_height=0.5)[0])) * bin_deg
        if int(width / bin_deg) <= distance:
            break
        distance = int(width / bin_deg)
    return centres[peaks], width


def _merge_drifting(peaks: np.ndarray, az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Merge neighbouring peaks that are one beam whose elevation drifts with range: a beam has
    one elevation at one azimuth, so two peaks whose returns rarely share an azimuth (one where
    the beam hits the ground, one where a wall stops it nearer) are one beam. Real neighbouring
    beams see the same ground and walls: most azimuths hold returns of both."""
    peaks = np.sort(peaks)
    bins = np.floor(np.mod(az, 360.0)).astype(np.int64)
    while len(peaks) > 2:
        labels = np.clip(np.round(_fractional_index(el, peaks)).astype(np.int64), 0, len(peaks) - 1)
        seen = np.zeros((len(peaks), 360), dtype=bool)
        seen[labels, bins] = True
        counts = seen.sum(axis=1)
        shared = (seen[:-1] & seen[1:]).sum(axis=1) / np.maximum(np.minimum(counts[:-1], counts[1:]), 1)
        k = int(np.argmin(shared))
        if shared[k] >= _MIN_SHARED_AZIMUTHS:
            break
        weight = np.bincount(labels, minlength=len(peaks)).astype(np.float64)
        merged = (peaks[k] * weight[k] + peaks[k + 1] * weight[k + 1]) / max(weight[k] + weight[k + 1], 1.0)
        peaks = np.r_[peaks[:k], merged, peaks[k + 2 :]]
    return peaks


def _columns(az: np.ndarray, table: np.ndarray, el: np.ndarray, cells_a_return: float) -> int:
    """Firings a turn from the returns within a fifth of a spacing of each beam (nearer its
    neighbours they may be a neighbour's, at another azimuth phase), at most ``cells_a_return``
    cells a return over the azimuths the scan covers: where the beams are not resolved a "beam"
    holds several rings, whose points would otherwise count as firings."""
    u = _fractional_index(el, table)
    k = np.clip(np.round(u).astype(np.int64), 0, len(table) - 1)
    core = np.abs(u - k) < 0.2
    firings = firings_per_turn(az[core], k[core], len(table))
    covered = max(1.0, float(np.unique(np.floor(np.mod(az, 360.0))).size))
    bound = math.ceil(cells_a_return * len(el) / len(table) * 360.0 / covered)
    return max(1, min(firings or bound, bound, int(360 / MIN_AZIMUTH_STEP_DEG), MAX_RAYS // len(table)))


def _uniform(az: np.ndarray, el: np.ndarray, peaks: int, spread: float | None = None) -> Guess:
    lo, hi = (float(v) for v in np.quantile(el, [0.001, 0.999]))
    covered = max(1.0, float(np.unique(np.floor(np.mod(az, 360.0))).size))
    spacing = math.sqrt(max(hi - lo, 0.1) * covered / len(el))  # about one return a cell
    beams = int(np.clip(round((hi - lo) / spacing) + 1, 2, MAX_BEAMS))
    columns = int(np.clip(round(360.0 / spacing), 1, min(360 / MIN_AZIMUTH_STEP_DEG, MAX_RAYS // beams)))
    table = np.linspace(lo, hi, beams)
    if spread is not None:
        why = (f"{peaks} histogram peaks that do not hold the returns: {spread:.2f} spacings RMS from the nearest, "
               f"uniform elevations give 0.29")
    elif peaks < 2:
        why = "no significant histogram peak"
    else:
        why = f"{peaks} histogram peaks, more than {MAX_BEAMS} beams"
    rule = (
        f"no beam table in the elevations ({why}): a uniform {beams} x {columns} grid, "
        f"{360.0 / columns:.3f} deg, about one return a cell"
    )
    return Guess(Reading(table, 360.0 / columns, {"angular density (deg)": round(spacing, 4)}), METHOD_UNIFORM, rule)


def _apparent(table: np.ndarray, el_sensor: np.ndarray, el_data: np.ndarray) -> np.ndarray:
    """The table as the scan's frame sees it: each beam's median elevation in the data over the
    returns nearest it in the sensor's frame (a beam with none: its place, moved by the median
    difference between the two frames)."""
    labels = np.clip(np.round(_fractional_index(el_sensor, table)).astype(np.int64), 0, len(table) - 1)
    out = table + float(np.median(el_data - el_sensor))
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(len(table) + 1))
    for k in range(len(table)):
        if bounds[k + 1] > bounds[k]:
            out[k] = np.median(el_data[order[bounds[k] : bounds[k + 1]]])
    return np.sort(out)


def guess_beams(az: np.ndarray, el: np.ndarray, r: np.ndarray, bin_deg: float = 0.02, *, quick: bool = False) -> Guess:
    """A beam table and azimuth step for returns with no ring labels (rules in the docstring;
    ``quick``: the histogram rules only, in the scan's own frame)."""
    el_sensor, frame = (el, {}) if quick else level(az, el, r)
    best, fits = (None, []) if quick else _snap(el_sensor)
    tried = {f.preset: [round(f.spread, 3), round(f.occupied, 2)] for f in fits[:3]}
    if best is not None:
        columns = _columns(az, best.table, el_sensor, 2.0)
        stats = {
            "preset": best.preset,
            "offset (deg)": round(best.offset, 3),
            "spread (spacings)": round(best.spread, 3),
            **frame,
            "closest presets [spread, occupied]": tried,
        }
        rule = (
            f"snapped to preset {best.preset}: returns within {best.spread:.2f} spacings (RMS) of its table "
            f"moved by {best.offset:+.2f} deg (tolerance: spread <= {MAX_SPREAD}, offset <= {MAX_OFFSET_DEG} "
            f"deg, beams moved <= {MAX_BEAM_SHIFT} spacings)"
        )
        table = _apparent(best.table, el_sensor, el) if frame else best.table
        return Guess(Reading(table, 360.0 / columns, stats), METHOD_PRESET, rule)
    peaks, width = _peaks(el_sensor, bin_deg)
    if 2 < len(peaks) <= MAX_BEAMS:
        peaks = _merge_drifting(peaks, az, el_sensor)
    if not 2 <= len(peaks) <= MAX_BEAMS:  # no beams, or more than a spinning LiDAR has: a grid
        return _uniform(az, el, len(peaks))
    # Where the peaks are tight the returns nearest each are one ring's; where they are not, a
    # peak holds several rings and its firings are bounded by one cell a return.
    u = _fractional_index(el_sensor, np.sort(peaks))
    spread = float(np.sqrt(np.mean((u - np.round(u)) ** 2)))
    if spread > MAX_TABLE_SPREAD:
        return _uniform(az, el, len(peaks), spread)
    columns = _columns(az, np.sort(peaks), el_sensor, 2.0 if spread <= MAX_SPREAD else 1.0)
    stats = {
        "significant peaks": len(peaks),
        "peak width (deg)": round(width, 3),
        "spread (spacings)": round(spread, 3),
        **frame,
        "closest presets [spread, occupied]": tried,
    }
    rule = (
        f"elevation histogram: {len(peaks)} significant peaks, no preset within tolerance (the count is "
        f"bounded by the data's elevation resolution, {width:.2f} deg)"
    )
    table = _apparent(np.sort(peaks), el_sensor, el) if frame else np.sort(peaks)
    return Guess(Reading(table, 360.0 / columns, stats), METHOD_HISTOGRAM, rule)
