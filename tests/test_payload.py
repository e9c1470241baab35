from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from lwbench import Payload, PayloadError, pack_points, unpack_points
from lwbench.payload import FORMAT_VERSION


def _payload() -> bytes:
    pose = np.eye(4)
    pose[:3, 3] = [1.0, -2.0, 0.5]
    return Payload("raw", {"k": 1, "sensor": {"preset": "vlp16"}}, b"\x01\x02\x03body", pose).to_bytes()


def test_round_trip_preserves_every_field():
    p = Payload.from_bytes(_payload())
    assert p.codec_id == "raw" and p.meta == {"k": 1, "sensor": {"preset": "vlp16"}}
    assert p.body == b"\x01\x02\x03body"
    np.testing.assert_allclose(p.pose[:3, 3], [1.0, -2.0, 0.5], atol=1e-6)
    assert Payload.from_bytes(p.to_bytes()).to_bytes() == p.to_bytes()


@pytest.mark.parametrize("cut", [1, 4, 10, 20])
def test_truncated_payload_raises(cut):
    with pytest.raises(PayloadError):
        Payload.from_bytes(_payload()[:-cut])


def test_every_single_flipped_byte_is_detected():
    data = bytearray(_payload())
    for i in range(len(data)):
        bad = bytearray(data)
        bad[i] ^= 0x40
        with pytest.raises(PayloadError):
            Payload.from_bytes(bytes(bad))


def test_wrong_magic_raises():
    with pytest.raises(PayloadError, match="not an lwbench payload"):
        Payload.from_bytes(b"PK\x03\x04" + _payload()[4:])


def test_future_version_raises_even_with_a_valid_checksum():
    data = bytearray(_payload()[:-4])
    data[4] = FORMAT_VERSION + 1
    data += struct.pack("<I", zlib.crc32(bytes(data)))
    with pytest.raises(PayloadError, match="version"):
        Payload.from_bytes(bytes(data))


def test_payload_for_another_codec_raises():
    with pytest.raises(PayloadError, match="not 'gmm'"):
        Payload.from_bytes(_payload(), expect_codec="gmm")


def test_point_serializer_float32_is_lossless():
    pts = np.random.default_rng(1).normal(0, 20, (1000, 3)).astype(np.float32)
    body = pack_points(pts)
    assert len(body) == 5 + 12 * 1000
    np.testing.assert_array_equal(unpack_points(body), pts)


@pytest.mark.parametrize("step", [0.001, 0.01, 0.05])
def test_point_serializer_quantized_error_is_at_most_half_a_step(step):
    pts = np.random.default_rng(2).uniform(-60, 60, (5000, 3)).astype(np.float32)
    back = unpack_points(pack_points(pts, "quantized", step))
    assert np.abs(back - pts).max() <= step / 2 + 1e-5 * 60


def test_quantized_points_use_16_bits_when_the_extent_allows():
    pts = np.random.default_rng(3).uniform(0, 10, (100, 3)).astype(np.float32)
    assert len(pack_points(pts, "quantized", 0.01)) == 5 + 17 + 6 * 100
    assert len(pack_points(pts, "quantized", 0.0001)) == 5 + 17 + 12 * 100


def test_point_body_of_wrong_size_raises():
    body = pack_points(np.zeros((10, 3), np.float32))
    with pytest.raises(PayloadError):
        unpack_points(body[:-1])


def test_a_derived_sensor_travels_as_a_short_id_not_its_table():
    from lwbench import SensorModel
    from lwbench.registry import get_registry
    from lwbench.testing import room_scan

    table = tuple(float(e) for e in np.linspace(-24.9, 2.1, 64) + np.random.default_rng(0).normal(0, 0.05, 64))
    sensor = SensorModel("derived", table, 360 / 2000, 0.9, 120.0, 10.0)
    frame = room_scan(sensor, seed=1)
    vsgp = get_registry().codec("vsgp")
    codec = vsgp(num_inducing=50)
    data = codec.encode(frame)
    meta = Payload.from_bytes(data).meta
    assert meta["sensor"] == {"id": sensor.sensor_id}
    header = len(data) - len(Payload.from_bytes(data).body)
    assert header < 120, header  # the full table would be ~1.5 kB of JSON
    fresh = SensorModel("derived", table, 360 / 2000, 0.9, 120.0, 10.0)
    assert fresh.sensor_id == sensor.sensor_id
    # The encoder's own instance knows what it wrote ...
    assert len(codec.decode(data)) > 0
    # ... a receiver handed the stream's sensors resolves among those only: told about another
    # sensor, it refuses clearly, whatever else this process encoded before ...
    other = SensorModel("other", table[:-1], 360 / 2000, 0.9, 120.0, 10.0)
    with pytest.raises(PayloadError, match="not known to this receiver"):
        vsgp().use_sensors([other]).decode(data)
    # ... and decodes once it is handed the stream's table.
    assert len(vsgp().use_sensors([fresh]).decode(data)) > 0
    # A bare decoder is told nothing: no process-wide memory of what was encoded (issue 34).
    with pytest.raises(PayloadError, match="use_sensors"):
        vsgp().decode(data)


def test_a_run_decodes_from_the_bytes_and_the_dataset_not_from_process_state():
    """The runner hands the fresh decoder the frame's sensor: it never reaches the deprecated
    process memory (which would warn), even for a derived sensor named by id."""
    import warnings

    from lwbench.registry import get_registry
    from lwbench.run.evaluate import encode_decode
    from lwbench.run.plan import CodecConfig
    from lwbench.testing import check_frames

    frame = check_frames()["hdl32-ring"]
    assert frame.sensor.to_wire() == {"id": frame.sensor.sensor_id}
    cls = get_registry().codec("rangeimage")
    config = CodecConfig("rangeimage", cls().config)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        enc = encode_decode(cls, config, cls(**config.params), frame)
    assert len(enc.decoded) > 0


def test_a_decoder_resolves_only_the_sensors_it_was_handed_not_what_the_process_encoded():
    """The process-wide sensor registry is gone (issue 34, item 6): a bare decoder of a payload
    naming a derived sensor by id fails with the fix in the message, however many encoders of the
    process wrote that sensor; handed the sensor, it decodes."""
    import lwbench
    from lwbench import PayloadError, SensorModel
    from lwbench.registry import get_registry
    from lwbench.testing import room_scan

    cls = get_registry().codec("rangeimage")
    sensor = SensorModel("derived-old", tuple(np.linspace(-10, 10, 8)), 1.0, 0.1, 20.0, 10.0)
    data = cls().encode(room_scan(sensor, seed=2))
    with pytest.raises(PayloadError, match="use_sensors"):
        cls().decode(data)
    assert len(cls().use_sensors([sensor]).decode(data)) > 0
    assert not hasattr(lwbench, "register_sensor")


def test_a_sensor_id_names_exactly_one_table():
    from lwbench import SensorModel, get_sensor

    a = get_sensor("hdl64e").with_max_range(80.0)
    b = SensorModel(a.name, a.elevations_deg[:-1] + (a.elevations_deg[-1] + 1e-6,), a.azimuth_step_deg,
                    a.min_range, a.max_range, a.rate_hz)
    assert a.sensor_id != b.sensor_id and len(a.sensor_id) == 16
    assert get_sensor("vlp16").to_wire() == {"preset": "vlp16"}
    assert a.to_wire() == {"id": a.sensor_id}
