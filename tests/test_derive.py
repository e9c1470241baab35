"""Deriving a sensor model from a scan: from the point order when there is no ring field,
the histogram only as a (warned) last resort, and a check that two scans share a sensor."""

from __future__ import annotations

import numpy as np
import pytest
from _scans import interleaved, spinning_scan

from lwbench import SensorModel, get_sensor
from lwbench.io import read_kitti_bin, read_ouster_metadata, read_point_file
from lwbench.sensors.derive import (
    METHOD_FIRING_MAJOR,
    METHOD_PRESET,
    METHOD_RING_FIELD,
    METHOD_RING_MAJOR,
    METHOD_UNIFORM,
    DataWarning,
    derive_sensor,
    sensor_mismatch,
)

HDL64E = get_sensor("hdl64e")


def _table_error(derived: SensorModel, truth: SensorModel) -> float:
    assert derived.n_beams == truth.n_beams
    return float(np.abs(np.subtract(derived.elevations_deg, truth.elevations_deg)).max())


def test_ring_major_order_recovers_the_table_where_the_histogram_cannot():
    # Each laser's elevation spreads by more than the beams are apart (as on KITTI): the
    # histogram of a shuffled copy finds the wrong number of beams; the order finds all 64.
    pts = spinning_scan("hdl64e", order="ring", elevation_noise_deg=0.25, dropout=0.1)
    d = derive_sensor(pts)
    assert d.method == METHOD_RING_MAJOR and d.exact
    assert _table_error(d.sensor, HDL64E) < 0.05
    assert d.sensor.n_azimuth == HDL64E.n_azimuth  # the step between neighbours, not the count
    assert d.stats["rings"] == 64
    shuffled = pts[np.random.default_rng(0).permutation(len(pts))]
    # Shuffled, the beams blur into a smooth histogram: its few bumps hold the returns no better
    # than uniform elevations would, so no table is made of them (issue 32: 12 "beams" for a
    # 64-beam keyframe set) -- a flagged uniform grid at the data's density.
    with pytest.warns(DataWarning, match=r"sensor model guessed \(no beam table.*do not hold the returns.*sensor="):
        guess = derive_sensor(shuffled)
    assert guess.method == METHOD_UNIFORM and not guess.exact
    assert guess.notes and any("ring-major" in n for n in guess.notes)


def test_ring_major_with_a_seam_behind_the_sensor_and_clockwise_rotation():
    s = get_sensor("os1-128")
    pts = spinning_scan(s, order="ring", start_deg=150.0, dropout=0.2)
    pts[:, 1] *= -1  # mirror: the azimuth now decreases along each ring, as on an Ouster
    d = derive_sensor(pts)
    assert d.method == METHOD_RING_MAJOR
    assert _table_error(d.sensor, s) < 1e-3 and d.sensor.n_azimuth == 1024


def test_a_cropped_ring_major_scan_keeps_its_rings_and_says_it_is_cropped():
    pts = spinning_scan("hdl64e", order="ring", fov_deg=90, elevation_noise_deg=0.1)
    with pytest.warns(DataWarning, match="covers only 9[01] of 360 deg"):
        d = derive_sensor(pts)
    assert d.method == METHOD_RING_MAJOR and _table_error(d.sensor, HDL64E) < 0.05


def test_firing_major_interleaved_lasers_with_dropped_returns():
    # HDL-32E driver order: one azimuth per firing, lasers interleaved, missing returns removed.
    s = SensorModel("hdl32", tuple(np.linspace(-30.67, 10.67, 32)), 360 / 2170, 1.0, 100.0, 10.0)
    pts = spinning_scan(s, order="firing", laser_order=interleaved(32), dropout=0.03)
    d = derive_sensor(pts)
    assert d.method == METHOD_FIRING_MAJOR and d.stats["firings split by"] == "shared azimuth"
    assert _table_error(d.sensor, s) < 1e-3 and d.sensor.n_azimuth == 2170


def test_firing_major_with_per_laser_azimuth_offsets_splits_at_elevation_resets():
    pts = spinning_scan("hdl64e", order="firing", dropout=0.01, azimuth_offsets_deg=np.tile([3, 1, -1, -3], 16))
    d = derive_sensor(pts)
    assert d.method == METHOD_FIRING_MAJOR and d.stats["firings split by"] == "elevation resets"
    assert _table_error(d.sensor, HDL64E) < 1e-3
    assert d.sensor.n_azimuth == pytest.approx(2048, rel=0.01)


def test_azimuths_rounded_by_the_driver_give_the_mean_step_not_the_rounded_one():
    s = SensorModel("s", tuple(np.linspace(-15, 15, 16)), 360 / 2170, 0.5, 100.0, 10.0)
    pts = spinning_scan(s, order="firing").astype(np.float64)
    az = np.round(np.degrees(np.arctan2(pts[:, 1], pts[:, 0])), 2)  # 0.01 deg, as Velodyne packets
    rho = np.hypot(pts[:, 0], pts[:, 1])
    pts[:, 0], pts[:, 1] = rho * np.cos(np.radians(az)), rho * np.sin(np.radians(az))
    d = derive_sensor(pts)  # steps are 0.16 or 0.17 deg; the median alone would say one of those
    assert d.sensor.n_azimuth == pytest.approx(2170, abs=3)


def test_ring_field_is_used_when_given():
    s = get_sensor("vlp16")
    pts = spinning_scan(s, order="ring", elevation_noise_deg=0.5)
    ring = np.repeat(np.arange(16), 3600)
    keep = np.random.default_rng(0).permutation(len(pts))[: len(pts) // 2]  # no order left
    d = derive_sensor(pts[keep], ring=ring[keep])
    assert d.method == METHOD_RING_FIELD
    assert _table_error(d.sensor, s) < 0.05 and d.sensor.n_azimuth == 3600
    with pytest.raises(ValueError, match="ring must have shape"):
        derive_sensor(pts, ring=ring[:-1])


def test_from_points_delegates_to_the_derivation():
    pts = spinning_scan("vlp16", order="firing", dropout=0.1)
    assert SensorModel.from_points(pts, rate_hz=4.0) == derive_sensor(pts, rate_hz=4.0).sensor


def test_same_sensor_with_missing_beams_is_not_a_mismatch():
    full = derive_sensor(spinning_scan("hdl64e", order="ring", seed=1))
    top_missing = spinning_scan("hdl64e", order="ring", seed=2)
    top_missing = top_missing[top_missing[:, 2] / np.linalg.norm(top_missing, axis=1) < np.sin(np.radians(-3))]
    assert sensor_mismatch(full, derive_sensor(top_missing)) is None
    assert sensor_mismatch(derive_sensor(top_missing), full) is not None  # beams the model lacks


@pytest.mark.parametrize("other", ["vlp16", "os1-128"])
def test_a_different_sensor_is_a_mismatch_both_ways(other):
    a = derive_sensor(spinning_scan("hdl64e", order="ring"))
    b = derive_sensor(spinning_scan(other, order="ring", ranges=(4.0, 9.0)))
    assert sensor_mismatch(a, b) is not None and sensor_mismatch(b, a) is not None


# ------------------------------------------------------------------------------ real samples
def test_kitti_hdl64e_without_ring_field_has_64_beams_and_2000_odd_columns(real_data):
    for name in ("000000.bin", "000001.bin"):
        d = derive_sensor(read_kitti_bin(real_data / "kitti00_frames0-1" / name).points)
        assert d.method == METHOD_RING_MAJOR and d.sensor.n_beams == 64
        # HDL-64E S2 at 10 Hz: 0.1728 deg between firings (~2,083 per turn)
        assert d.sensor.azimuth_step_deg == pytest.approx(0.1728, abs=0.002)
        assert d.sensor.elevations_deg[0] < -22 and 1.5 < d.sensor.elevations_deg[-1] < 3.5


def test_ouster_ring_major_order_matches_its_own_metadata(real_data):
    folder = real_data / "ouster_os1-128_seq3"
    meta = read_ouster_metadata(folder / "sensor_metadata.json")
    d = derive_sensor(read_kitti_bin(folder / "000000.bin").points)
    assert d.method == METHOD_RING_MAJOR and d.sensor.n_beams == 128 and d.sensor.n_azimuth == meta.n_azimuth
    # per-ring medians vs the beam altitudes: within the beams' own spread (origin offset)
    assert np.abs(np.subtract(d.sensor.elevations_deg, meta.elevations_deg)).max() < 0.5


def test_hdl32_pcd_in_firing_order_gives_the_hdl32e_table(real_data):
    for name in ("source.pcd", "target.pcd"):
        d = derive_sensor(read_point_file(real_data / "hdl32_pair" / name).points)
        assert d.method == METHOD_FIRING_MAJOR and d.sensor.n_beams == 32
        np.testing.assert_allclose(d.sensor.elevations_deg, np.linspace(-30.67, 10.67, 32), atol=0.01)
        assert 2100 < d.sensor.n_azimuth < 2250


def test_a_scan_order_lwbench_does_not_know_snaps_to_its_preset_with_a_warning(real_data):
    # A Pandar64 (its table to 0.01 deg) whose laser order is neither ring- nor firing-major: the
    # histogram found 34 beams; the preset's table fits the elevations (61 rings seen, 3 top ones
    # face the sky), so the guess is the sensor's 64 beams -- still a guess, and said to be one.
    scan = read_point_file(real_data / "lidar64_static_pcd" / "2021-10-26-16-21-29-468.pcd")
    assert derive_sensor(scan.points, ring=scan.ring).sensor.n_beams == 61
    with pytest.warns(DataWarning, match=r"guessed \(snapped to preset pandar64"):
        d = derive_sensor(scan.points)
    assert d.method == METHOD_PRESET and d.guessed and len(d.notes) == 2
    assert d.sensor.n_beams == 64 and d.sensor.azimuth_step_deg == pytest.approx(0.2, abs=0.002)
