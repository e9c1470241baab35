"""The noise floor: the bits per point no codec that keeps every return can go below.

A LiDAR's range is measured with noise of standard deviation ``sigma`` (the sensor model's
``range_noise_m``). Even a codec that predicted the true surface perfectly would still have to
code that noise, to the accuracy it keeps the range to. With a uniform step ``step`` the
quantized noise has the entropy of a Gaussian cut into bins of width ``step``:

- fine steps (``step <= sigma``): the differential entropy of a Gaussian less the step,
  ``log2(sigma * sqrt(2*pi*e)) - log2(step) = log2(sigma / step) + 2.0471`` bits per return
  (:func:`gaussian_step_bits`; the constant is ``0.5 * log2(2*pi*e)``, exactly, not a fit);
- every step: :func:`quantized_gaussian_bits`, the exact entropy of the binned Gaussian, which
  equals the closed form within 0.001 bit for ``step <= sigma / 10`` (0.015 bit at ``sigma / 2``,
  0.06 at ``sigma``) and goes to 0 (never below) as the step grows past the noise, where the
  closed form turns negative. The floor uses this exact sum.

A codec's distortion is stated as a range RMSD, not a step: a uniform quantizer of step ``step``
makes an error of RMSD ``step / sqrt(12)``, so the floor *at a distortion* ``d`` is the rate at
``step = sqrt(12) * d`` (:func:`step_for_rmsd`). That makes the floor a curve, bits per point
against range RMSD (:meth:`ScanFloor.bits_per_point`), on which a codec's point can be placed:
its distance to the floor, in bits per point, is what better coding could still win. (Shannon's
rate-distortion bound of a Gaussian, ``log2(sigma / d)``, is 0.254 bit lower at fine steps: the
space-filling loss of any scalar quantizer, ``0.5 * log2(pi * e / 6)``. The floor is the scalar
quantizer's, which is what every codec here is.)

The second part is the **no-return mask**: which rays of the sensor's grid returned. It is
*measured from the scan's own range image* (:func:`mask_bits`): the empirical entropy of each
cell's return bit given its left and upper neighbour (an order-2 context model, as JBIG's),
which is never above the binary entropy of the grid's fill ratio (also reported, as a bound).
The floor counts it once per scan, spread over the scan's points.

What the floor leaves out makes it a lower bound: it takes a return's direction as known from
the grid (a real sensor's directions scatter around the cell centres, which costs bits the floor
does not count), it codes no intensity, and it is the floor of a codec that keeps every return
(a codec that drops returns -- voxel, random, keypoints -- is below it by construction; its RMSD
is over the returns it kept, and the board flags its coverage). A configuration whose range
RMSD is exactly 0 (raw floats) has no finite floor: ``None``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from lwbench.frame import Frame

__all__ = [
    "GAUSSIAN_ENTROPY_BITS",
    "FloorIds",
    "MaskBits",
    "ScanFloor",
    "draw_floor",
    "entry_floor",
    "floor_bits_per_point",
    "floor_lines",
    "gaussian_step_bits",
    "mask_bits",
    "print_floor",
    "quantized_gaussian_bits",
    "scan_floor",
    "step_for_rmsd",
]

#: ``0.5 * log2(2*pi*e)``: the differential entropy of a unit Gaussian, in bits (2.0471).
GAUSSIAN_ENTROPY_BITS = 0.5 * math.log2(2.0 * math.pi * math.e)
_SQRT12 = math.sqrt(12.0)


def gaussian_step_bits(sigma: float, step: float) -> float:
    """``log2(sigma * sqrt(2*pi*e)) - log2(step)``: the fine-step entropy of Gaussian noise of
    standard deviation ``sigma`` quantized at ``step`` (negative for ``step > 4.13 sigma``, where
    the approximation no longer holds: use :func:`quantized_gaussian_bits`)."""
    if not (sigma > 0 and step > 0):
        raise ValueError(f"sigma and step must be positive, got {sigma}, {step}")
    return math.log2(sigma / step) + GAUSSIAN_ENTROPY_BITS


def quantized_gaussian_bits(sigma: float, step: float) -> float:
    """The exact entropy (bits) of a zero-mean Gaussian of standard deviation ``sigma`` binned by a
    mid-tread quantizer of width ``step``: ``-sum p_k log2 p_k`` over every bin holding more than
    1e-300 of the mass. Why not the closed form alone: it is an approximation that goes negative
    at coarse steps, where a codec's error is above the noise and the noise costs ~0 bits."""
    if not (sigma > 0 and step > 0):
        raise ValueError(f"sigma and step must be positive, got {sigma}, {step}")
    from scipy.special import ndtr

    ratio = step / sigma
    if ratio < 1e-3:  # ~ 10^4 bins; the closed form is exact to 1e-7 bit there
        return gaussian_step_bits(sigma, step)
    k_max = int(math.ceil(40.0 / ratio)) + 1  # 40 sigma: beyond, no mass a float64 holds
    edges = (np.arange(-k_max, k_max + 2, dtype=np.float64) - 0.5) * ratio
    p = np.diff(ndtr(edges))
    p = p[p > 1e-300]
    return float(max(0.0, -(p * np.log2(p)).sum()))


def step_for_rmsd(rmsd: float) -> float:
    """The uniform step whose quantization error has this RMSD: ``sqrt(12) * rmsd``."""
    return _SQRT12 * rmsd


@dataclass(frozen=True)
class MaskBits:
    """The return/no-return pattern of one scan's range image, in bits."""

    bits: float  # measured: the order-2 context entropy (left, upper neighbour), whole grid
    bound_bits: float  # the binary entropy of the fill ratio, times the cells: an upper bound
    cells: int
    returns: int

    @property
    def fill(self) -> float:
        return self.returns / self.cells if self.cells else 0.0


def _entropy_bits(ones: np.ndarray, totals: np.ndarray) -> float:
    """Sum over contexts of ``n * H_b(ones / n)`` (bits), for counts of ones out of totals."""
    out = 0.0
    for k, n in zip(ones.tolist(), totals.tolist(), strict=True):
        if 0 < k < n:
            p = k / n
            out -= n * (p * math.log2(p) + (1 - p) * math.log2(1 - p))
    return out


def mask_bits(occupied: np.ndarray) -> MaskBits:
    """The entropy of a range image's return mask (``occupied``: ``(beams, columns)`` bool).

    Each cell's bit is coded given its left neighbour (the azimuth wraps: column 0's left is the
    last column) and its upper neighbour (the row above; row 0's is taken as "returned"), with
    the empirical probability of each of the four contexts -- the cost an adaptive order-2
    context coder approaches. Why contexts: the mask is sky and near-range runs, not coin flips,
    so the fill ratio's binary entropy (``bound_bits``) overstates it several times on a road."""
    occ = np.asarray(occupied, dtype=bool)
    if occ.ndim != 2 or occ.size == 0:
        raise ValueError(f"a range image mask must be a non-empty 2-D array, got shape {occ.shape}")
    left = np.roll(occ, 1, axis=1)
    up = np.vstack([np.ones((1, occ.shape[1]), dtype=bool), occ[:-1]])
    context = left.astype(np.int64) * 2 + up.astype(np.int64)
    totals = np.bincount(context.ravel(), minlength=4)
    ones = np.bincount(context.ravel(), weights=occ.ravel().astype(np.float64), minlength=4).astype(np.int64)
    n, k = int(occ.size), int(occ.sum())
    return MaskBits(_entropy_bits(ones, totals), _entropy_bits(np.array([k]), np.array([n])), n, k)


@dataclass(frozen=True)
class ScanFloor:
    """The floor of one scan: its sensor's range noise, its mask's bits and its point count."""

    sigma: float  # m, the sensor model's range_noise_m
    mask: MaskBits
    points: int

    @property
    def mask_bpp(self) -> float:
        """The mask's bits spread over the scan's points (every point is a return to code)."""
        return self.mask.bits / self.points if self.points else 0.0

    def bits_per_point(self, rmsd: float) -> float | None:
        """The floor at a range RMSD (m): mask + the noise quantized at ``sqrt(12) * rmsd``."""
        return floor_bits_per_point(rmsd, self.sigma, self.mask_bpp)


def floor_bits_per_point(rmsd: float | None, sigma: float | None, mask_bpp: float | None) -> float | None:
    """The floor (bits per point) at range RMSD ``rmsd`` for noise ``sigma`` and a mask of
    ``mask_bpp`` bits per point; ``None`` where it has no finite value (an exact, 0, RMSD; no
    noise figure)."""
    if rmsd is None or sigma is None or mask_bpp is None or not (rmsd > 0 and sigma > 0):
        return None
    return mask_bpp + quantized_gaussian_bits(sigma, step_for_rmsd(rmsd))


def scan_floor(frame: Frame) -> ScanFloor:
    """The floor of ``frame``: its sensor model's ``range_noise_m`` and the mask of its own range
    image (:meth:`~lwbench.SensorModel.project`, returns inside the sensor's range limits)."""
    occupied = frame.sensor.project(np.asarray(frame.points, dtype=np.float64)).valid
    return ScanFloor(float(frame.sensor.range_noise_m), mask_bits(occupied), len(frame.points))


# -- the floor of stored results (``lwbench rd``, ``lwbench report``) ------------------------
@dataclass(frozen=True)
class FloorIds:
    """The metric ids the floor of stored results reads, found by the quantity each declares
    (:data:`lwbench.metric.QUANTITIES`), never by name: core knows no metric by name."""

    distortion: str  # range_error_rms
    bits_per_point: str
    input_points: str
    sigma: str  # range_noise_sigma
    mask_bpp: str  # mask_bits_per_point

    @classmethod
    def from_info(cls, info: Mapping[str, Any]) -> FloorIds | None:
        """From a board's metric info; ``None`` when an installed metric does not declare one of
        the quantities (no floor is drawn, nothing else changes)."""
        from lwbench.metric import ids_by_quantity

        found = ids_by_quantity(info)
        wanted = ("range_error_rms", "rate_bits_per_point", "input_points", "range_noise_sigma", "mask_bits_per_point")
        if not all(q in found for q in wanted):
            return None
        return cls(*(found[q] for q in wanted))


def entry_floor(entry: Any, ids: FloorIds) -> float | None:
    """The floor (bits per point) at a board entry's mean range error, from the mean floor inputs
    its rows stored (the metric declaring them); ``None`` without them or at a range error of 0."""
    return floor_bits_per_point(entry.value(ids.distortion), entry.value(ids.sigma), entry.value(ids.mask_bpp))


def floor_lines(entries: Iterable[Any], ids: FloorIds,
                shown: Mapping[tuple[str, str], Any] | None = None) -> list[str]:
    """One ``floor`` line per dataset: the floor's bits per point at each configuration's range
    error and the configuration's distance to it (its bits per point less the floor). ``shown``:
    the curves of ``lwbench rd`` (only their configurations are listed), else every entry."""
    entries = list(entries)
    keep = None
    if shown is not None:
        keep = {(ds, p.label) for (ds, _), c in shown.items() for p in c.points}
    by_ds: dict[str, list[str]] = {}
    for e in entries:
        if keep is not None and (e.dataset, e.label) not in keep:
            continue
        floor = entry_floor(e, ids)
        bpp = e.value(ids.bits_per_point)
        if floor is None:
            text = "exact (no finite floor)" if e.value(ids.distortion) == 0 else None
            if text is None:
                continue
            by_ds.setdefault(e.dataset, []).append(f"{e.label} {text}")
            continue
        gap = f" ({bpp - floor:+.2f})" if bpp is not None else ""
        if bpp is not None and bpp < floor:
            # No codec can beat the floor of the noise the data carries: below it, the declared
            # range noise is more than the scans hold (a sensor model's datasheet figure).
            gap += " BELOW THE FLOOR: the declared range noise is too high for these scans"
        by_ds.setdefault(e.dataset, []).append(f"{e.label} {floor:.2f}{gap}")
    out = []
    for ds, items in by_ds.items():
        sigma = next((e.value(ids.sigma) for e in entries if e.dataset == ds and e.value(ids.sigma)), None)
        mask = next((e.value(ids.mask_bpp) for e in entries if e.dataset == ds and e.value(ids.sigma)), None)
        head = f"floor on {ds} (bits/point at each {ids.distortion}, + the codec's distance to it"
        head += f"; sigma {sigma * 1000:.3g} mm, mask {mask:.3f} bit/point)" if sigma and mask is not None else ")"
        out.append(f"{head}: " + "; ".join(items))
    return out


def print_floor(entries: list[Any], curves: Mapping[tuple[str, str], Any] | None, info: Mapping[str, Any],
                say: Callable[[str], Any]) -> None:
    """``lwbench rd``'s floor lines, given to ``say`` (the console's print); none when the
    installed metrics do not declare the floor's quantities."""
    ids = FloorIds.from_info(info)
    if ids is not None:
        for line in floor_lines(entries, ids, curves):
            say(line)


def draw_floor(ax: Any, entries: list[Any], distortion: str, rate: str, ids: FloorIds) -> bool:
    """Draw the noise floor on an RD plot of ``distortion`` against ``rate`` (bytes per frame or
    ``ids.bits_per_point``), labelled ``noise floor``: for the range error the floor curve over
    the plot's distortion range, for any other distortion each configuration's floor rate at its
    own distortion (the rate its range accuracy needs at least), as unjoined markers. False if
    there is nothing to draw."""
    rows = [(e, entry_floor(e, ids)) for e in entries if not e.flags]  # flagged ones are off the curves too
    rows = [(e, f) for e, f in rows if f is not None and e.value(distortion) is not None]
    if not rows:
        return False

    def to_rate(bpp: float, e: Any) -> float:
        return bpp if rate == ids.bits_per_point else bpp * (e.value(ids.input_points) or 0.0) / 8.0

    if distortion == ids.distortion:
        # The floor curve over the configurations' distortions (beyond them it would stretch the
        # rate axis by decades: at a distortion far above the noise the floor is the mask alone).
        sigma = float(np.mean([e.value(ids.sigma) for e, _ in rows]))
        mask = float(np.mean([e.value(ids.mask_bpp) for e, _ in rows]))
        points = float(np.mean([e.value(ids.input_points) or 0.0 for e, _ in rows]))
        d_all = [e.value(distortion) for e, _ in rows]
        d = np.geomspace(min(d_all) / 1.5, max(d_all) * 1.5, 60)
        bpp = np.array([floor_bits_per_point(x, sigma, mask) for x in d])
        keep = bpp > 0.01
        x = bpp[keep] if rate == ids.bits_per_point else bpp[keep] * points / 8.0
        ax.plot(x, d[keep], ls="--", lw=1.2, color="0.35", label="noise floor")
    else:
        # One point per configuration, not a line: the floor is defined at each configuration's own
        # range accuracy, and joining the points of different codecs drew a zig-zag where the floor
        # has no value (issue 33).
        ax.plot(
            [to_rate(f, e) for e, f in rows],
            [e.value(distortion) for e, _ in rows],
            ls="none",
            marker="x",
            ms=5,
            color="0.35",
            label="noise floor",
        )
    return True
