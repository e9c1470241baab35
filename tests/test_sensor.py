from __future__ import annotations

import numpy as np
import pytest

from lwbench import SENSOR_PRESETS, SensorModel, get_sensor
from lwbench.io import read_ouster_metadata


def test_vlp16_preset_is_the_vsgp_papers_sensor():
    s = get_sensor("vlp16")
    assert s.shape == (16, 3600)
    assert s.n_rays == 57_600
    assert s.max_range == 10.0 and s.rate_hz == 4.0
    assert s.elevations_deg[0] == pytest.approx(-15) and s.elevations_deg[-1] == pytest.approx(15)


@pytest.mark.parametrize("name", sorted(SENSOR_PRESETS))
def test_range_image_round_trip_is_exact_on_cell_centres(name):
    s = get_sensor(name)
    rng = np.random.default_rng(0)
    ranges = rng.uniform(s.min_range + 0.5, s.max_range - 0.5, s.shape).astype(np.float32)
    ranges[rng.random(s.shape) < 0.3] = 0  # some cells without a return
    img = s.project(s.unproject(ranges))
    np.testing.assert_allclose(img.ranges, ranges, rtol=1e-5, atol=1e-4)
    assert (img.index >= 0).sum() == (ranges > 0).sum()


def test_projection_keeps_the_nearest_return_per_cell(tiny_sensor):
    d = tiny_sensor.ray_directions()[1, 2]
    pts = np.stack([d * 7.0, d * 3.0, d * 5.0])
    img = tiny_sensor.project(pts)
    assert img.ranges[1, 2] == pytest.approx(3.0)
    assert img.index[1, 2] == 1
    assert (img.ranges > 0).sum() == 1


def test_projection_drops_points_outside_the_range_window(tiny_sensor):
    d = tiny_sensor.ray_directions()[0, 0]
    img = tiny_sensor.project(np.stack([d * 0.05, d * 25.0]))
    assert not img.valid.any()
    assert tiny_sensor.project(np.stack([d * 25.0]), clip_range=False).valid.sum() == 1


def test_sensor_dict_round_trip_for_presets_and_custom_tables():
    s = get_sensor("hdl64e")
    assert s.to_dict() == {"preset": "hdl64e"}
    assert SensorModel.from_dict(s.to_dict()) == s
    custom = SensorModel("mine", (-10.0, 0.0, 10.0), 0.5, 0.2, 30.0, 5.0)
    back = SensorModel.from_dict(custom.to_dict())
    assert back == custom and back.n_rays == 3 * 720


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ValueError, match="vlp16"):
        get_sensor("nope")


def test_derive_from_a_scan_with_rings_recovers_the_beam_table():
    s = get_sensor("vlp16")
    dirs = s.ray_directions()
    pts = (dirs * 6.0).reshape(-1, 3)
    ring = np.repeat(np.arange(16), 3600)
    derived = SensorModel.from_points(pts, ring=ring, rate_hz=4.0)
    np.testing.assert_allclose(derived.elevations_deg, s.elevations_deg, atol=1e-6)
    assert derived.n_azimuth == 3600


def test_derive_without_rings_finds_the_beams_from_the_elevation_histogram():
    s = get_sensor("vlp16")
    pts = (s.ray_directions() * 6.0).reshape(-1, 3)
    derived = SensorModel.from_points(pts)
    assert derived.n_beams == 16
    np.testing.assert_allclose(derived.elevations_deg, s.elevations_deg, atol=0.05)


def test_ouster_metadata_gives_its_own_beam_table(real_data):
    s = read_ouster_metadata(real_data / "ouster_os1-128_seq3" / "sensor_metadata.json")
    assert s.n_beams == 128 and s.n_azimuth == 1024 and s.rate_hz == 10.0


def test_every_preset_has_a_range_noise_from_its_datasheet_and_a_source():
    from lwbench.sensors.specs import DERIVED_RANGE_NOISE_M, SENSOR_SPECS

    assert set(SENSOR_SPECS) == set(SENSOR_PRESETS)
    for name, spec in SENSOR_SPECS.items():
        s = get_sensor(name)
        assert 0.005 <= s.range_noise_m <= 0.05 and s.range_noise_m == spec.range_noise_m, name
        assert spec.source and s.n_beams == len(spec.elevations_deg), name
    for name, beams in (("hdl32e", 32), ("vlp32c", 32), ("pandar64", 64), ("pandarqt", 64), ("os0-128", 128)):
        assert get_sensor(name).n_beams == beams
    assert SensorModel("d", (-1.0, 1.0), 0.5, 0.1, 50.0, 10.0).range_noise_m == DERIVED_RANGE_NOISE_M


def test_range_noise_round_trips_and_old_dicts_still_read():
    s = SensorModel("mine", (-10.0, 0.0, 10.0), 0.5, 0.2, 30.0, 5.0, range_noise_m=0.012)
    d = s.to_dict()
    assert d["range_noise_m"] == 0.012 and SensorModel.from_dict(d) == s
    old = {k: v for k, v in d.items() if k != "range_noise_m"}  # a sensor.json written before it existed
    back = SensorModel.from_dict(old)
    assert back.range_noise_m == 0.03 and back.elevations_deg == s.elevations_deg
    # The id is the geometry's: a payload that named the old model by id still finds it.
    assert back.sensor_id == s.sensor_id
    import hashlib
    import json

    blob = json.dumps(old, sort_keys=True, separators=(",", ":")).encode()
    assert s.sensor_id == hashlib.sha256(blob).hexdigest()[:16]
    with pytest.raises(TypeError, match="range_noise_m"):
        SensorModel.from_dict({**d, "range_noise_m": "loud"})
    with pytest.raises(ValueError, match="range noise"):
        SensorModel("x", (0.0,), 1.0, 0.1, 10.0, 10.0, range_noise_m=-1.0)
    assert get_sensor("hdl64e").to_dict() == {"preset": "hdl64e"}
