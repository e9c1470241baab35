"""Rate-distortion curves and the Bjøntegaard deltas against hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lwbench.metric import HIGHER, LOWER
from lwbench.results.rd import Curve, Point, RDError, bd_distortion, bd_rate, pareto_front


def _curve(rates, dists, better=LOWER, codec="c") -> Curve:
    points = (Point(r, d, f"{codec}{i}") for i, (r, d) in enumerate(zip(rates, dists, strict=True)))
    return Curve(codec, "d", tuple(points), better)


RATES = [1000.0, 2000.0, 4000.0, 8000.0, 16000.0]
RMSD = [0.20, 0.12, 0.07, 0.04, 0.025]


def test_a_curve_against_itself_is_zero():
    c = _curve(RATES, RMSD)
    assert bd_rate(c, c) == pytest.approx(0.0, abs=1e-9)
    assert bd_distortion(c, c) == pytest.approx(0.0, abs=1e-9)


def test_the_same_curve_at_half_the_bytes_is_minus_fifty_percent():
    ref = _curve(RATES, RMSD)
    half = _curve([r / 2 for r in RATES], RMSD)
    assert bd_rate(ref, half) == pytest.approx(-50.0, abs=1e-9)
    assert bd_rate(half, ref) == pytest.approx(100.0, abs=1e-9)


def test_bd_distortion_of_a_uniformly_better_curve_by_hand():
    # Every RMSD divided by 2 at the same rates: -20 log10(d/2) = -20 log10(d) + 6.0206 dB.
    ref = _curve(RATES, RMSD)
    better = _curve(RATES, [d / 2 for d in RMSD])
    assert bd_distortion(ref, better) == pytest.approx(20 * math.log10(2), abs=1e-9)


def test_psnr_in_db_is_used_as_is():
    ref = _curve(RATES, [30.0, 34.0, 38.0, 42.0, 46.0], HIGHER)
    up = _curve(RATES, [31.0, 35.0, 39.0, 43.0, 47.0], HIGHER)
    assert bd_distortion(ref, up, unit="dB") == pytest.approx(1.0, abs=1e-9)


def test_too_few_points_or_no_overlap_is_a_clear_error():
    with pytest.raises(RDError, match="at least 4"):
        bd_rate(_curve(RATES[:3], RMSD[:3]), _curve(RATES, RMSD))
    far = _curve([r * 1e3 for r in RATES], [d / 1e3 for d in RMSD])
    with pytest.raises(RDError, match="do not overlap"):
        bd_rate(_curve(RATES, RMSD), far)


def test_the_pareto_front_drops_beaten_points_and_interpolation_never_extrapolates():
    pts = [Point(r, d, str(i)) for i, (r, d) in enumerate(zip(RATES, RMSD, strict=True))]
    pts.append(Point(3000.0, 0.3, "beaten"))
    front = pareto_front(pts, LOWER)
    assert [p.label for p in front] == ["0", "1", "2", "3", "4"]
    c = Curve("c", "d", tuple(front), LOWER)
    assert c.distortion_at(500.0) is None and c.distortion_at(20000.0) is None
    # log-linear between 1000 and 2000 bytes: at the geometric mean, the arithmetic mean.
    assert c.distortion_at(math.sqrt(2) * 1000) == pytest.approx(0.16)
    assert c.rate_at(0.16) == pytest.approx(math.sqrt(2) * 1000)
    assert c.rate_at(0.5) is None
    assert np.all(np.diff(c.rates) > 0)
