"""Range-image codec: exact lossless image, quantized error <= step/2, self-contained bytes,
beam tables the decoder always accepts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from lwbench_plugins.rangeimage import RangeImageCodec, pack_image, unpack_image
from lwbench_plugins.rangeimage.beams import fit_beam_table, offset_code_bounds, read_beam_table

from lwbench import Frame, Payload, PayloadError, SensorModel, get_sensor
from lwbench.testing import NO_RETURN, hdl32_ring_scan


def ouster_sensor(folder: Path) -> SensorModel:
    """The recording's own beam table (not the uniform preset)."""
    meta = json.loads((folder / "sensor_metadata.json").read_text())
    return SensorModel("os1-128-seq3", tuple(meta["beam_altitude_angles"]), 360 / 1024, 0.3, 120.0, 10.0)


def scan(seed: int = 0, sensor: str = "vlp16") -> Frame:
    """A scan with off-ray jitter, several returns per cell, out-of-range and empty cells:
    everything the projection has to decide about."""
    s = get_sensor(sensor)
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.5, 9.5, s.shape)
    ranges[rng.random(s.shape) < 0.2] = 0.0
    pts = s.unproject(ranges).astype(np.float64)
    pts += rng.normal(scale=0.01, size=pts.shape)
    extra = pts[rng.choice(len(pts), 2000)] * rng.uniform(0.9, 1.1, (2000, 1))
    far = rng.normal(size=(50, 3)) * 50
    return Frame(np.concatenate([pts, extra, far]).astype(np.float32), s)


def test_pack_image_round_trip_including_extreme_values() -> None:
    rng = np.random.default_rng(0)
    for width in (2, 4):
        top = (1 << (8 * width)) - 1
        v = rng.integers(0, top + 1, size=(7, 33))
        v[:, 0], v[:, 1], v[0, :] = top, 0, top  # largest jumps both ways
        for predict in ("none", "row-delta"):
            for shuffle in (False, True):
                raw = pack_image(v, width, predict, shuffle)
                assert len(raw) == v.size * width
                np.testing.assert_array_equal(unpack_image(raw, v.shape, width, predict, shuffle), v)


@pytest.mark.parametrize("predict", ["none", "row-delta"])
@pytest.mark.parametrize("shuffle", ["auto", "on", "off"])
def test_lossless_reproduces_the_range_image_exactly(predict: str, shuffle: str) -> None:
    frame = scan()
    codec = RangeImageCodec(mode="lossless", predict=predict, shuffle=shuffle)
    sensor, ranges = RangeImageCodec().decode_image(codec.encode(frame))
    assert sensor == frame.sensor
    expected = frame.sensor.project(frame.points).ranges
    assert ranges.dtype == np.float32
    np.testing.assert_array_equal(ranges.view(np.uint32), expected.view(np.uint32))  # bit for bit
    # The decoded points are the image's cell centres, so re-projecting them lands in the same
    # cells with the same ranges (up to float32 rounding of x, y, z).
    points = codec.decode(codec.encode(frame))
    assert len(points) == int((expected > 0).sum())
    again = frame.sensor.project(points).ranges
    np.testing.assert_array_equal(again > 0, expected > 0)
    np.testing.assert_allclose(again, expected, rtol=1e-6, atol=0)


@pytest.mark.parametrize("step", [0.003, 0.01, 0.05])
def test_quantized_error_is_at_most_half_a_step(step: float) -> None:
    frame = scan(seed=1)
    expected = frame.sensor.project(frame.points).ranges
    _, ranges = RangeImageCodec().decode_image(RangeImageCodec(step=step).encode(frame))
    np.testing.assert_array_equal(ranges > 0, expected > 0)
    err = np.abs(ranges.astype(np.float64) - expected)[expected > 0]
    assert err.max() <= step / 2 + 1e-5
    assert err.max() > step / 4  # rounding really happened: the bound is tight, not vacuous


def test_wide_integers_when_the_range_needs_them() -> None:
    frame = scan(seed=2)  # 9.5 m / 0.1 mm = 95,000 > 2**16
    data = RangeImageCodec(step=1e-4).encode(frame)
    assert Payload.from_bytes(data).meta["width"] == 4
    _, ranges = RangeImageCodec().decode_image(data)
    expected = frame.sensor.project(frame.points).ranges
    assert np.abs(ranges - expected).max() <= 0.5e-4 + 1e-6


def test_prediction_and_shuffle_shrink_a_real_like_scan() -> None:
    # Smooth tunnel-like walls plus 3 mm range noise: neighbours along a row are close but not
    # equal, as in a real scan (noise-free synthetic rows repeat and zstd alone finds them).
    s = get_sensor("vlp16")
    az = s.azimuths_rad()[None, :]
    el = s.elevations_rad[:, None]
    ranges = 2.0 / np.maximum(np.abs(np.sin(el)), 0.25) * (1 + 0.1 * np.cos(3 * az))
    ranges = ranges + np.random.default_rng(0).normal(0, 0.003, s.shape)
    frame = Frame(s.unproject(ranges), s)
    plain = len(RangeImageCodec(predict="none", shuffle="off").encode(frame))
    best = len(RangeImageCodec(predict="row-delta", shuffle="on").encode(frame))
    assert best < 0.8 * plain


def test_sensor_travels_in_the_payload() -> None:
    frame = scan(sensor="vlp16")
    custom = SensorModel("custom", tuple(np.linspace(-10, 10, 8)), 0.5, 0.2, 20.0, 5.0)
    frame = Frame(frame.points, custom)
    data = RangeImageCodec().encode(frame)
    sensor, _ = RangeImageCodec().decode_image(data)
    # SensorModel.to_dict rounds the beam table to 1e-5 deg (9 um at 100 m), so compare that way.
    assert sensor == SensorModel.from_dict(custom.to_dict())
    np.testing.assert_allclose(sensor.elevations_deg, custom.elevations_deg, atol=1e-5)
    assert sensor.shape == custom.shape
    preset = RangeImageCodec(sensor="vlp16").encode(frame)
    assert RangeImageCodec().decode_image(preset)[0] == get_sensor("vlp16")
    assert Payload.from_bytes(preset).meta["sensor"] == {"preset": "vlp16"}


def test_deterministic_and_independent_of_the_decoder_instance() -> None:
    frame = scan(seed=3)
    a = RangeImageCodec(step=0.02, level=5).encode(frame)
    assert a == RangeImageCodec(step=0.02, level=5).encode(frame)
    np.testing.assert_array_equal(
        RangeImageCodec(mode="lossless").decode(a), RangeImageCodec(step=1.0).decode(a)
    )


def _rewrap(data: bytes, body: bytes | None = None, **meta: object) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, {**p.meta, **meta}, p.body if body is None else body, p.pose).to_bytes()


def test_corrupt_payloads_raise_payload_error() -> None:
    frame = scan()
    codec = RangeImageCodec()
    data = codec.encode(frame)
    body = Payload.from_bytes(data).body
    cases = [
        _rewrap(data, body[: len(body) // 2]),  # truncated zstd frame
        _rewrap(data, b"\x00" * 64),  # not zstd
        _rewrap(data, width=4),  # decompressed size disagrees with the grid
        _rewrap(data, width=3),
        _rewrap(data, mode="jpeg"),
        _rewrap(data, predict="paeth"),
        _rewrap(data, step=-0.01),
        _rewrap(data, step="1cm"),
        _rewrap(data, sensor={"preset": "nope"}),
        _rewrap(data, sensor={"name": "x", "elevations_deg": [0.0], "azimuth_step_deg": 1e-6,
                              "min_range": 0.1, "max_range": 10.0, "rate_hz": 10.0}),  # 360M cells
        _rewrap(data, sensor="vlp16"),
        data[:-1],
        Payload("draco", {}, body).to_bytes(),
    ]
    for bad in cases:
        with pytest.raises(PayloadError):
            codec.decode(bad)
    lossless = RangeImageCodec(mode="lossless").encode(frame)
    nan_image = np.full(frame.sensor.n_rays, np.nan, dtype="<f4").view("<u4").astype(np.int64)
    import zstandard

    nan_body = zstandard.ZstdCompressor().compress(
        pack_image(nan_image.reshape(frame.sensor.shape), 4, "none", False)
    )
    with pytest.raises(PayloadError):
        codec.decode(_rewrap(lossless, nan_body, predict="none", shuffle=False))


def test_real_ouster_scan(real_data: Path) -> None:
    ouster = real_data / "ouster_os1-128_seq3"
    pts = np.fromfile(ouster / "000000.bin", dtype=np.float32).reshape(-1, 4)[:, :3]
    frame = Frame(pts, ouster_sensor(ouster))
    image = frame.sensor.project(pts).ranges
    for step in (0.01, 0.05):
        data = RangeImageCodec(step=step).encode(frame)
        _, ranges = RangeImageCodec().decode_image(data)
        assert np.abs(ranges - image).max() <= step / 2 + 1e-5
        # Measured 13.7x (1 cm) and 19.5x (5 cm) on this frame; a regression shows up here.
        assert frame.raw_bytes / len(data) > (11 if step == 0.01 else 16)
    _, exact = RangeImageCodec().decode_image(RangeImageCodec(mode="lossless").encode(frame))
    np.testing.assert_array_equal(exact, image)


def beam_offset_scan() -> tuple[Frame, np.ndarray, np.ndarray]:
    """Each beam fires at its own phase inside the columns and a little off its table
    elevation, like an Ouster: the refined decode should recover both."""
    s = get_sensor("vlp16")
    rng = np.random.default_rng(7)
    phase = rng.uniform(0.05, 0.95, s.n_beams)
    offset = np.radians(rng.uniform(-0.3, 0.3, s.n_beams))
    rows, cols = np.indices(s.shape).reshape(2, -1)
    az = -np.pi + (cols + phase[rows]) * s.azimuth_step_rad
    el = s.elevations_rad[rows] + offset[rows]
    r = rng.uniform(1.0, 9.0, len(rows))
    pts = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * r[:, None]
    return Frame(pts.astype(np.float32), s), phase, offset


def test_beam_refinement_puts_points_back_on_their_rays() -> None:
    frame, _, _ = beam_offset_scan()
    image = frame.sensor.project(frame.points)
    original = frame.points[image.index[image.valid]]  # row-major cell order, as decoded
    err = {}
    for refine in ("none", "beam"):
        codec = RangeImageCodec(mode="lossless", refine=refine)
        data = codec.encode(frame)
        decoded = RangeImageCodec().decode(data)
        assert decoded.shape == original.shape
        err[refine] = np.linalg.norm(decoded - original, axis=1)
        # Either way the decoded points fall back into their own cells with their ranges.
        again = frame.sensor.project(decoded)
        np.testing.assert_array_equal(again.valid, image.valid)
        np.testing.assert_allclose(again.ranges, image.ranges, rtol=1e-6)
    # Phase quantized to 1/255 cell (0.1 deg / 255), elevation to 1e-5 rad: < 0.1 mm at 9 m.
    assert err["beam"].max() < 1e-4
    assert err["none"].mean() > 100 * err["beam"].mean()
    beam_size = len(RangeImageCodec(mode="lossless", refine="beam").encode(frame))
    none_size = len(RangeImageCodec(mode="lossless", refine="none").encode(frame))
    assert beam_size - none_size <= 3 * frame.sensor.n_beams + 16


def test_beam_refinement_is_exact_on_centre_rays() -> None:
    # Points already on the cell centres (the simulator's case) must stay there exactly.
    s = get_sensor("vlp16")
    ranges = np.random.default_rng(3).uniform(1, 9, s.shape)
    frame = Frame(s.unproject(ranges), s)
    decoded = RangeImageCodec(mode="lossless", refine="beam").decode(
        RangeImageCodec(mode="lossless", refine="beam").encode(frame)
    )
    np.testing.assert_allclose(decoded, frame.points, atol=2e-6)


def test_corrupt_beam_table_raises_payload_error() -> None:
    import zstandard

    frame, _, _ = beam_offset_scan()
    data = RangeImageCodec(refine="beam").encode(frame)
    p = Payload.from_bytes(data)
    raw = bytearray(zstandard.ZstdDecompressor().decompress(p.body))
    n = frame.sensor.n_beams
    bad_phase = bytearray(raw)
    bad_phase[0] = 255  # phase codes stop at 254
    bad_elev = bytearray(raw)
    bad_elev[n + 2 : n + 4] = np.array([30000], "<i2").tobytes()  # 17 deg: far outside the band
    for bad in (bad_phase, bad_elev, raw[:-1]):
        body = zstandard.ZstdCompressor().compress(bytes(bad))
        with pytest.raises(PayloadError):
            RangeImageCodec().decode(Payload(p.codec_id, p.meta, body, p.pose).to_bytes())
    with pytest.raises(PayloadError):
        RangeImageCodec().decode(_rewrap(data, refine="spline"))
    # The same body read as unrefined is the wrong size.
    with pytest.raises(PayloadError):
        RangeImageCodec().decode(_rewrap(data, refine="none"))


def test_quantized_ranges_stay_inside_the_sensor_window() -> None:
    s = get_sensor("vlp16")  # 0.1 .. 10 m
    ranges = np.full(s.shape, 9.99)
    ranges[:, ::2] = 0.12
    frame = Frame(s.unproject(ranges), s)
    decoded = RangeImageCodec(step=0.05).decode(RangeImageCodec(step=0.05).encode(frame))
    assert len(decoded) == len(frame)
    # Rounded to 10.00 / 0.10 m, the points must still be inside the window when re-projected.
    again = s.project(decoded).ranges
    assert (again > 0).all()
    assert np.abs(again - ranges).max() <= 0.025 + 1e-5


def test_ring_derived_table_with_coincident_beams_round_trips() -> None:
    """Issue 11: a 32-beam scan with a ring field, whose sky-facing rings mostly hold the
    sensor's "no return" point, so their per-ring medians -- the derived beam table --
    coincide. Version 2 wrote a beam table its own decoder refused ("beam elevation offset
    leaves the beam's band"): the allowed band of a beam between coincident neighbours was
    empty, and clipping into it returned its upper end, below its lower end."""
    frame = hdl32_ring_scan()
    no_return_el = np.degrees(np.arcsin(NO_RETURN[2] / np.linalg.norm(NO_RETURN)))
    # The table version 2 met: per-ring medians that counted the no-return points (the ring
    # field reading now leaves them out, issue 25), so four sky-facing rings sit at theirs.
    polluted = np.asarray(frame.sensor.elevations_deg)
    polluted[-4:] = no_return_el
    d = frame.sensor
    s = SensorModel("polluted", tuple(polluted), d.azimuth_step_deg, 0.0, d.max_range, d.rate_hz)
    frame = Frame(frame.points, s, ring=frame.ring, intensity=frame.intensity)
    e = np.asarray(s.elevations_deg)
    coincident = np.isclose(e, no_return_el)
    assert coincident.sum() >= 3  # the condition that broke version 2
    image = s.project(frame.points)
    for mode in ("quantized", "lossless"):
        data = RangeImageCodec(mode=mode).encode(frame)
        decoded = RangeImageCodec().decode(data)
        assert len(decoded) == int(image.valid.sum())
        _, ranges = RangeImageCodec().decode_image(data)
        np.testing.assert_array_equal(ranges > 0, image.valid)
    np.testing.assert_array_equal(ranges, image.ranges)  # lossless: bit for bit
    # Away from the coincident beams, refined points still fall back into their own cells.
    again = s.project(decoded)
    ordinary = ~coincident[:, None] & image.valid
    assert (again.valid | ~ordinary).all()
    np.testing.assert_allclose(again.ranges[ordinary], image.ranges[ordinary], rtol=1e-5)


def _points_at(sensor: SensorModel, el: np.ndarray, n_az: int = 64) -> np.ndarray:
    az = np.linspace(-np.pi, np.pi, n_az, endpoint=False) + 1e-3
    el, az = np.meshgrid(el, az, indexing="ij")
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1).reshape(-1, 3)
    return (d * 10.0).astype(np.float32)


@pytest.mark.parametrize(
    "table",
    [
        np.linspace(-15, 15, 16),  # VLP-16
        np.r_[np.linspace(-30, -2, 29), -1.0, -1.0, -1.0],  # three coincident beams
        np.r_[-20.0, -1.0, -1.0 + 1e-3, -1.0 + 2e-3, 5.0],  # closer than the margins
        np.r_[-1.0, -1.0],  # nothing but one elevation
        np.r_[-70.0, 0.0, 70.0],  # bands wider than the int16 cap
        np.r_[3.0],  # one beam
    ],
    ids=["vlp16", "coincident", "sub-margin", "all-equal", "wide", "single"],
)
def test_encoder_writes_only_offset_codes_the_decoder_accepts(table: np.ndarray) -> None:
    """Whatever the table and wherever the returns lie (on the band edges, or far outside
    the outer beams), the codes fit in int16, include 0, and read back."""
    s = SensorModel("t", tuple(table), 360 / 64, 0.1, 100.0, 10.0)
    q_lo, q_hi = offset_code_bounds(s)
    assert (q_lo <= 0).all() and (q_hi >= 0).all() and q_lo.min() >= -32768 and q_hi.max() <= 32767
    e = s.elevations_rad
    mids = (e[1:] + e[:-1]) / 2
    # Every allowed code keeps the beam's ray inside its projection band (not towards a
    # neighbour it coincides with, which has no band to move into).
    assert (e[1:] + q_lo[1:] * 1e-5 >= mids - 1e-12).all() and (e[:-1] + q_hi[:-1] * 1e-5 <= mids + 1e-12).all()
    el = np.r_[e, mids, mids - 1e-9, mids + 1e-9, e[0] - 1.2, e[-1] + 1.2]
    el = el[np.abs(el) < np.pi / 2 - 1e-3]
    pts = _points_at(s, el)
    for chosen in (slice(None), np.isin(el, mids - 1e-9), np.isin(el, mids + 1e-9)):
        sub = _points_at(s, el[chosen])
        image = s.project(sub)
        table_bytes = fit_beam_table(s, sub, image)
        _, offset = read_beam_table(table_bytes, s)  # would raise PayloadError if refused
        codes = np.rint(offset / 1e-5)
        assert ((codes >= q_lo) & (codes <= q_hi)).all()
    frame = Frame(pts, s)
    RangeImageCodec().decode(RangeImageCodec().encode(frame))


def test_decoder_accepts_exactly_the_allowed_offset_codes() -> None:
    import zstandard

    frame, _, _ = beam_offset_scan()
    data = RangeImageCodec(refine="beam").encode(frame)
    p = Payload.from_bytes(data)
    raw = bytearray(zstandard.ZstdDecompressor().decompress(p.body))
    n = frame.sensor.n_beams
    q_lo, q_hi = offset_code_bounds(frame.sensor)

    def decode_with(beam: int, code: int) -> np.ndarray:
        table = bytearray(raw)
        table[n + 2 * beam : n + 2 * beam + 2] = np.array([code], "<i2").tobytes()
        body = zstandard.ZstdCompressor().compress(bytes(table))
        return RangeImageCodec().decode(Payload(p.codec_id, p.meta, body, p.pose).to_bytes())

    for beam in (0, 7, n - 1):
        assert len(decode_with(beam, int(q_lo[beam]))) == len(decode_with(beam, int(q_hi[beam])))
        for code in (int(q_lo[beam]) - 1, int(q_hi[beam]) + 1):
            with pytest.raises(PayloadError):
                decode_with(beam, code)
