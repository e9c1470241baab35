"""Issue 25, done-when: rotating a scan about the sensor axis before encoding, by any fraction of
an azimuth step, moves no codec's coverage by more than 0.01.

A real sensor's firings fall anywhere against a fixed azimuth grid (the simulator's fall on cell
centres); a codec whose grid is anchored to 0 degrees instead of to the scan's own firings sees a
different scan at each rotation (issue 25: VSGP's coverage on a 16-beam cave went from 0.455 to
0.998, rangeimage's from 0.739 to 1.0). Here every registered codec, at its defaults, encodes each
of the kit's scans (:func:`lwbench.testing.check_frames` plus the tunnel) turned by 0, 0.13, 0.25,
0.5 and 0.77 of the sensor's azimuth step -- the sensor model stays as it was, as a loader that
derived it once would keep it -- and decodes the bytes the way a run does (a fresh decoder told
only the sensor: :func:`lwbench.run.evaluate.encode_decode`); coverage is the range metric's.

The learners that take seconds per encode (gmm, vsgp, poconet) are ``slow``; the rest stay well
under the fast suite's share.
"""

from __future__ import annotations

import numpy as np
import pytest
from _scans import rotated
from lwbench_metrics.ranges import RangeMetric

from lwbench import Frame, get_sensor
from lwbench.metric import Evaluation
from lwbench.registry import get_registry
from lwbench.run.evaluate import encode_decode
from lwbench.run.plan import CodecConfig
from lwbench.testing import check_frames, tunnel_scan

FRACTIONS = (0.0, 0.13, 0.25, 0.5, 0.77)
BOUND = 0.01  # the issue's: no codec's coverage moves by more than this
SLOW = {"gmm", "poconet", "vsgp"}  # seconds per encode at their defaults (gmm: 20-45 s a scan)
REGISTRY = get_registry()


def kit_scans() -> dict[str, Frame]:
    return {**check_frames(), "tunnel": tunnel_scan(seed=2)}




def coverage(codec: str, frame: Frame) -> float:
    """The range metric's coverage of ``frame`` through ``codec`` at its defaults, decoded by a
    fresh instance as the runner decodes."""
    cls = REGISTRY.codec(codec)
    config = CodecConfig(codec, {p.name: p.default for p in cls.all_params()})
    enc = encode_decode(cls, config, cls(**config.params), frame)
    ev = Evaluation(frame, enc.payload, enc.decoded, cls.kind, enc.timings_ms)
    value = RangeMetric().compute(ev)["coverage"]
    assert value is not None
    return value


def coverages(codec: str, scan: Frame) -> list[float]:
    step = scan.sensor.azimuth_step_rad
    return [coverage(codec, rotated(scan, f * step)) for f in FRACTIONS]


def _cases() -> list:
    cases = []
    for name, cls in sorted(REGISTRY.codecs.items()):
        marks = [pytest.mark.slow] if name in SLOW else []
        if cls.needs:  # the oracle: labels written for a posed sequence, which a kit scan is not
            marks.append(pytest.mark.skip(reason=f"{name} needs {cls.needs}"))
        cases.append(pytest.param(name, marks=marks, id=name))
    return cases


@pytest.mark.heavy
@pytest.mark.parametrize("codec", _cases())
def test_a_fraction_of_an_azimuth_step_moves_no_codecs_coverage(codec: str) -> None:
    moved = {}
    for scan_name, scan in kit_scans().items():
        cov = coverages(codec, scan)
        moved[scan_name] = (max(cov) - min(cov), [round(c, 4) for c in cov])
    worst = {k: v for k, v in moved.items() if v[0] > BOUND}
    assert not worst, f"{codec}: coverage over rotations {FRACTIONS} of a step moved by more than {BOUND}: {worst}"


def test_the_rotation_is_about_the_sensor_axis_and_keeps_the_scan() -> None:
    """The test's own transform: ranges, elevations and ring labels unchanged, azimuths moved by
    exactly the angle (so a codec that fails here failed on the same scan, turned)."""
    scan = check_frames()["hdl32-ring"]
    angle = 0.37 * scan.sensor.azimuth_step_rad
    turned = rotated(scan, angle)
    p, q = scan.points.astype(np.float64), turned.points.astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), np.linalg.norm(p, axis=1), rtol=1e-6)
    np.testing.assert_allclose(q[:, 2], p[:, 2], atol=1e-5)
    returns = np.linalg.norm(p[:, :2], axis=1) > 1.0
    delta = np.angle(np.exp(1j * (np.arctan2(q[:, 1], q[:, 0]) - np.arctan2(p[:, 1], p[:, 0]))))[returns]
    np.testing.assert_allclose(delta, angle, atol=1e-5)
    assert np.array_equal(turned.ring, scan.ring) and turned.sensor is scan.sensor


def _draco_range_rmsds(scan: Frame) -> list[float]:
    cls = REGISTRY.codec("draco")
    config = CodecConfig("draco", {p.name: p.default for p in cls.all_params()})
    out = []
    for f in FRACTIONS:
        turned = rotated(scan, f * scan.sensor.azimuth_step_rad)
        enc = encode_decode(cls, config, cls(**config.params), turned)
        ev = Evaluation(turned, enc.payload, enc.decoded, cls.kind, enc.timings_ms)
        value = RangeMetric().compute(ev)["range_rmsd"]
        assert value is not None
        out.append(value)
    return out


def _assert_within_5_percent(rmsds: list[float]) -> None:
    spread = [round(r / rmsds[0], 3) for r in rmsds]
    assert all(abs(s - 1) <= 0.05 for s in spread), f"range RMSD over rotations {FRACTIONS}, / unrotated: {spread}"


@pytest.mark.heavy
def test_draco_range_rmsd_does_not_move_when_near_returns_sit_before_far_ones() -> None:
    """Issue 32, item 5: Draco's ~mm position grid moves a return 1-2 m away by more than half an
    azimuth step, out of its own direction window, where a return metres behind it lies; version
    4 of the metric paired those (on this scan 2.67-4.08 mm over the rotations for 3.61 mm
    unrotated; version 5: 2.11-2.17 mm). Ranges drawn 1.2-60 m per ray put a depth edge beside
    every near return."""
    from _scans import spinning_scan

    sensor = get_sensor("hdl64e")
    _assert_within_5_percent(_draco_range_rmsds(Frame(spinning_scan(sensor, ranges=(1.2, 60.0), seed=3), sensor)))


@pytest.mark.heavy
def test_draco_range_rmsd_on_the_shared_kitti_frame_does_not_move(real_data) -> None:
    """Issue 32's done-when on the real frame: Draco's range RMSD within 5 % of its unrotated
    value at every fraction (version 4: 2.77 mm unrotated, 8.39 mm at a quarter step, from one
    pair 2.79 m apart)."""
    from _real import kitti_frame0

    frame = REGISTRY.dataset("kitti")(path=str(kitti_frame0().parent)).frame(0)
    _assert_within_5_percent(_draco_range_rmsds(frame))
