"""Rate-distortion: curves from a sweep, the Pareto front, values at equal rate or distortion,
and the Bjøntegaard deltas (BD-rate, BD-distortion) between two codecs.

A *curve* is one codec's (rate, distortion) points on one dataset -- one point per stored
configuration (a sweep of its parameters) -- reduced to its efficient part: the points no other
point of the same codec beats on both axes, in increasing rate. Rates are bytes per frame (or
bits per point); a distortion is any metric id with a declared direction (``range_rmsd``,
``chamfer``, ``d1_psnr``, ``ate_rmse``, ``occ_iou``, ...).

Interpolation is piecewise linear in log(rate) *within* a curve and never extrapolates: asking
a curve for a value outside the range it covers returns ``None``, which reports say as "does
not reach".

**Bjøntegaard deltas** (VCEG-M33, with the piecewise cubic Hermite interpolation (PCHIP) that
replaced the original cubic polynomial fit in the JCT-VC common test conditions, because the
polynomial overshoots on real curves):

- the quality axis is the distortion in dB: metrics in dB as they are (``d1_psnr``),
  lower-is-better distances as ``-20 log10(d)`` (what PSNR does to an RMSE), higher-is-better
  shares (IoU, coverage) as they are;
- BD-rate: the mean over the overlapping quality range of ``log10(rate_test) - log10(rate_ref)``
  at equal quality (each curve's log-rate interpolated as a PCHIP function of quality), reported
  as ``(10**mean - 1) * 100`` percent: negative = the test codec needs fewer bytes for the
  same quality. A curve against itself is 0 %; the same curve at half the bytes is -50 %.
- BD-distortion: the mean quality difference at equal log-rate over the overlapping rate range.

Both need at least 4 points on each curve (the method's requirement) and an overlapping range;
otherwise :class:`RDError` says which is missing.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lwbench.errors import LwbenchError
from lwbench.metric import ALL_CURVES, HIGHER, LOWER, MetricId

__all__ = [
    "Curve",
    "RDError",
    "TooFewPoints",
    "bd_distortion",
    "bd_rate",
    "curves_from_entries",
    "default_axes",
    "front_across",
    "left_out_flags",
    "pareto_front",
    "quality",
    "summarise",
]

MIN_BD_POINTS = 4


class RDError(LwbenchError):
    """A rate-distortion computation that the data cannot support (too few points, no overlap)."""


class TooFewPoints(RDError):
    """A curve with fewer efficient points than the Bjøntegaard delta needs (``curve`` says which)."""

    def __init__(self, message: str, curve: Curve) -> None:
        super().__init__(message)
        self.curve = curve


@dataclass(frozen=True)
class Point:
    rate: float
    distortion: float
    label: str


@dataclass(frozen=True)
class Curve:
    """One codec's efficient points, increasing in rate."""

    codec: str
    dataset: str
    points: tuple[Point, ...]
    better: str  # the distortion's direction: "lower" or "higher"

    @property
    def rates(self) -> np.ndarray:
        return np.array([p.rate for p in self.points])

    @property
    def distortions(self) -> np.ndarray:
        return np.array([p.distortion for p in self.points])

    def distortion_at(self, rate: float) -> float | None:
        """Distortion at ``rate`` by linear interpolation in log(rate); ``None`` outside the curve."""
        r, d = self.rates, self.distortions
        if not len(r) or rate < r[0] or rate > r[-1]:
            return None
        if len(r) == 1:
            return float(d[0])
        return float(np.interp(math.log(rate), np.log(r), d))

    def rate_at(self, distortion: float) -> float | None:
        """Rate needed for ``distortion`` (log-rate interpolated); ``None`` if never reached."""
        r, d = self.rates, self.distortions
        if not len(r):
            return None
        # Efficient points improve with rate: monotone in distortion, so invert piecewise.
        order = np.argsort(d)
        ds, lr = d[order], np.log(r[order])
        if distortion < ds[0] or distortion > ds[-1]:
            return None
        if len(r) == 1:
            return float(r[0])
        return float(math.exp(np.interp(distortion, ds, lr)))


def _dominates(a: Point, b: Point, better: str) -> bool:
    """``a`` is at least as good as ``b`` on both axes and better on one."""
    d_ok = a.distortion <= b.distortion if better == LOWER else a.distortion >= b.distortion
    d_strict = a.distortion < b.distortion if better == LOWER else a.distortion > b.distortion
    return a.rate <= b.rate and d_ok and (a.rate < b.rate or d_strict)


def pareto_front(points: list[Point], better: str) -> list[Point]:
    """The points no other point beats on both rate and distortion, in increasing rate."""
    front = [p for p in points if not any(_dominates(q, p, better) for q in points if q is not p)]
    return sorted(front, key=lambda p: (p.rate, p.distortion))


def left_out_flags(distortion: str, info: Mapping[str, MetricId] | None = None) -> set[str]:
    """Flags that keep a configuration off the curves of ``distortion``: failed rows always, and
    every guard that declares it (``Guard.off_curves``: low coverage for the range RMSD, which is
    measured over the paired returns only -- a codec that pairs 40 % of the scan has an RMSD over
    that 40 % -- and originals that fail ICP for every curve)."""
    out = {"failed_rows"}
    for m in (info or {}).values():
        guard = getattr(m, "guard", None)
        if guard is not None and (ALL_CURVES in guard.off_curves or distortion in guard.off_curves):
            out.add(guard.flag)
    return out


def default_axes(info: Mapping[str, MetricId]) -> tuple[str, str]:
    """``lwbench rd``'s distortion and rate when none is named: the ids declaring the quantities
    ``range_error_rms`` and ``bytes_per_frame``, else the first ``distortion`` and ``rate`` roles
    in board order -- found by declaration, never by name."""
    from lwbench.metric import ids_by_quantity

    found = ids_by_quantity(info)
    by_role = {role: next((str(i) for i, m in info.items() if getattr(m, "role", "") == role), None)
               for role in ("distortion", "rate")}
    distortion = found.get("range_error_rms") or by_role["distortion"]
    rate = found.get("bytes_per_frame") or by_role["rate"]
    if distortion is None or rate is None:
        raise RDError("no installed metric declares a distortion and a rate: name them with --distortion and --rate")
    return distortion, rate


def curves_from_entries(
    entries: list,
    distortion: str,
    *,
    rate: str,
    info: Mapping[str, MetricId] | None = None,
    left_out: list | None = None,
    limits: Mapping[str, float] | None = None,
) -> dict[tuple[str, str], Curve]:
    """One :class:`Curve` per (dataset, codec) from leaderboard entries (their mean values).
    Entries flagged as :func:`left_out_flags` says, or lacking either value, are left out (and
    appended to ``left_out`` as ``(entry, reason)``; the reason names the guard's value and limit,
    ``limits`` being the board's settings, e.g. ``{"min_coverage": 0.8}``)."""
    better = getattr((info or {}).get(distortion), "better", "") or LOWER
    if better not in (LOWER, HIGHER):
        raise RDError(f"{distortion} has no better direction, so it is not a distortion")
    skip = left_out_flags(distortion, info)
    grouped: dict[tuple[str, str], list[Point]] = defaultdict(list)
    for e in entries:
        r, d = e.shown(rate), e.shown(distortion)
        flag = next((f for f in e.flags if f in skip), None)
        reason = None if flag is None else _flag_reason(e, flag, info, limits or {})
        if reason is None and (r is None or d is None or not math.isfinite(r) or not math.isfinite(d) or r <= 0):
            reason = f"no finite {rate} / {distortion}"
        if reason is not None:
            if left_out is not None:
                left_out.append((e, reason))
            continue
        grouped[(e.dataset, e.codec)].append(Point(float(r), float(d), e.label))
    return {
        key: Curve(key[1], key[0], tuple(pareto_front(pts, better)), better)
        for key, pts in sorted(grouped.items())
    }


def _flag_reason(entry, flag: str, info: Mapping[str, MetricId] | None, limits: Mapping[str, float]) -> str:
    """``low_coverage (coverage 0.87 < 0.9; --min-coverage sets the limit)``: the flag, and the
    figure that raised it, so a user knows how far the point is from the curve."""
    for metric, m in (info or {}).items():
        guard = getattr(m, "guard", None)
        if guard is None or guard.flag != flag:
            continue
        value = entry.value(metric)
        limit = limits.get(guard.setting, guard.below if guard.below is not None else guard.above)
        if value is None or limit is None:
            return flag
        sign = "<" if guard.below is not None else ">"
        setting = f"; --{guard.setting.replace('_', '-')} sets the limit" if guard.setting else ""
        return f"{flag}: {metric} {value:.3g} {sign} {limit:g}{setting}"
    return flag


def quality(distortion: np.ndarray, better: str, unit: str = "") -> np.ndarray:
    """The quality axis of the Bjøntegaard deltas (see the module notes)."""
    d = np.asarray(distortion, dtype=np.float64)
    if unit == "dB" or better == HIGHER:
        return d
    if (d <= 0).any():
        raise RDError("a lower-is-better distortion of 0 (lossless) has no dB value: leave that point out")
    return -20.0 * np.log10(d)


def _pchip(x: np.ndarray, y: np.ndarray):
    from scipy.interpolate import PchipInterpolator

    order = np.argsort(x)
    x, y = x[order], y[order]
    if len(np.unique(x)) != len(x):
        raise RDError("two points of a curve share one value on the interpolation axis")
    return PchipInterpolator(x, y)


def _check(ref: Curve, test: Curve) -> None:
    for c in (ref, test):
        if len(c.points) < MIN_BD_POINTS:
            raise TooFewPoints(
                f"{c.codec} on {c.dataset}: {len(c.points)} efficient point(s); the Bjøntegaard delta needs "
                f"at least {MIN_BD_POINTS} per curve (sweep more settings)",
                c,
            )


def _mean_gap(xa: np.ndarray, ya: np.ndarray, xb: np.ndarray, yb: np.ndarray, what: str, shown=None) -> float:
    """Mean of ``f_b(x) - f_a(x)`` over the overlap of the two x ranges (PCHIP, exact integral).
    ``shown`` writes an x value as the user knows it (the rate in bytes, not its log10)."""
    lo, hi = max(xa.min(), xb.min()), min(xa.max(), xb.max())
    if not hi > lo:
        fmt = shown or (lambda x: f"{x:.4g}")
        raise RDError(f"the two curves do not overlap in {what} (reference {fmt(xa.min())}..{fmt(xa.max())} vs "
                      f"{fmt(xb.min())}..{fmt(xb.max())})")
    fa, fb = _pchip(xa, ya), _pchip(xb, yb)
    return float((fb.integrate(lo, hi) - fa.integrate(lo, hi)) / (hi - lo))


def bd_rate(ref: Curve, test: Curve, unit: str = "") -> float:
    """BD-rate of ``test`` against ``ref`` in percent (negative: ``test`` needs fewer bytes)."""
    _check(ref, test)
    qa, qb = quality(ref.distortions, ref.better, unit), quality(test.distortions, test.better, unit)
    gap = _mean_gap(qa, np.log10(ref.rates), qb, np.log10(test.rates), "quality", lambda q: f"{q:.4g} dB")
    return (10.0**gap - 1.0) * 100.0


def _rate_text(log_rate: float, rate_unit: str) -> str:
    rate = 10**log_rate
    text = f"{rate:,.0f}" if rate >= 100 else f"{rate:.3g}"
    return f"{text} {rate_unit}" if rate_unit else text


def bd_distortion(ref: Curve, test: Curve, unit: str = "", rate_unit: str = "") -> float:
    """BD-distortion: mean quality difference (dB, or the metric's unit) of ``test`` over ``ref``
    at equal rate (positive: ``test`` is better)."""
    _check(ref, test)
    qa, qb = quality(ref.distortions, ref.better, unit), quality(test.distortions, test.better, unit)
    return _mean_gap(np.log10(ref.rates), qa, np.log10(test.rates), qb, "rate", lambda lr: _rate_text(lr, rate_unit))


def front_across(curves: Mapping[tuple[str, str], Curve], dataset: str) -> list[tuple[str, Point]]:
    """The Pareto front over every codec's points on ``dataset``: (codec, point), by rate."""
    pts = [(c.codec, p) for (ds, _), c in curves.items() if ds == dataset for p in c.points]
    if not pts:
        return []
    better = next(c.better for (ds, _), c in curves.items() if ds == dataset)
    front = pareto_front([p for _, p in pts], better)
    owner = {id(p): codec for codec, p in pts}
    return [(owner[id(p)], p) for p in front]


def summarise(
    curves: Mapping[tuple[str, str], Curve],
    *,
    unit: str = "",
    at_rate: float | None = None,
    at_distortion: float | None = None,
    reference: str | None = None,
    left_out: list | None = None,
    rate_unit: str = "",
) -> dict[str, dict]:
    """Per dataset: each codec's curve, the front across codecs, values at an equal rate or
    distortion (``None`` = the curve does not reach it) and, with a ``reference`` codec, every
    other codec's BD-rate / BD-distortion against it (or the reason it cannot be computed: a
    curve short of points names the configurations ``left_out`` took from it, and why)."""
    out: dict[str, dict] = {}
    for (dataset, codec), curve in curves.items():
        ds = out.setdefault(dataset, {"curves": {}, "front": [], "at_rate": {}, "at_distortion": {}, "bd": {}})
        ds["curves"][codec] = [{"label": p.label, "rate": p.rate, "distortion": p.distortion} for p in curve.points]
        if at_rate is not None:
            ds["at_rate"][codec] = curve.distortion_at(at_rate)
        if at_distortion is not None:
            ds["at_distortion"][codec] = curve.rate_at(at_distortion)
    for dataset, ds in out.items():
        ds["front"] = [{"codec": c, "label": p.label, "rate": p.rate, "distortion": p.distortion}
                       for c, p in front_across(curves, dataset)]
        if reference is None:
            continue
        ref = curves.get((dataset, reference))
        for (d2, codec), curve in curves.items():
            if d2 != dataset or codec == reference:
                continue
            if ref is None:
                ds["bd"][codec] = {"error": f"no curve for the reference {reference!r} on this dataset"}
                continue
            ds["bd"][codec] = _deltas(ref, curve, unit, left_out or [], rate_unit)
    return out


def _deltas(ref: Curve, test: Curve, unit: str, left_out: list, rate_unit: str) -> dict:
    """BD-rate and BD-distortion, each on its own: curves that overlap in quality but not in rate
    (a coarse codec against a fine one) still get their BD-rate. ``error`` when neither exists,
    else ``bd_rate_error`` / ``bd_distortion_error`` for the one that does not."""
    out: dict = {}
    errors: list[str] = []
    for key, delta in (("bd_rate_pct", bd_rate), ("bd_distortion", bd_distortion)):
        try:
            out[key] = delta(ref, test, unit) if delta is bd_rate else delta(ref, test, unit, rate_unit)
        except TooFewPoints as exc:
            errors.append(str(exc) + _left_out_text(exc.curve, left_out))
            out[key.replace("_pct", "") + "_error"] = errors[-1]
        except RDError as exc:
            errors.append(str(exc))
            out[key.replace("_pct", "") + "_error"] = errors[-1]
    if len(errors) == 2:
        return {"error": errors[0] if errors[0] == errors[1] else "; ".join(errors)}
    return out


def _left_out_text(curve: Curve, left_out: list) -> str:
    """What a short curve lost: the configurations of its codec left off the curves, and why."""
    lost = [(e.label, why) for e, why in left_out if e.dataset == curve.dataset and e.codec == curve.codec]
    if not lost:
        return ""
    return f"; left out of {curve.codec}'s curve: " + "; ".join(f"{label} ({why})" for label, why in lost)
