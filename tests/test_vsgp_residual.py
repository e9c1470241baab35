"""VSGP's residual layer (``residual=TAU``, plugins/vsgp/residuals.py): every kept return within
TAU of its decoded range, a decoded point per return, the GP as a predictor and its control."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from _scans import rotated
from lwbench_plugins.vsgp import VSGPCodec
from lwbench_plugins.vsgp.residuals import (
    MAX_SLOTS,
    Slots,
    pack_residuals,
    residual_step,
    scan_slots,
    unpack_residuals,
)

from lwbench import Frame, ParameterError, Payload, PayloadError, get_sensor
from lwbench.testing import check_frames, tunnel_scan


def _round_trip(frame: Frame, **params) -> tuple[bytes, np.ndarray]:
    data = VSGPCodec(device="cpu", **params).encode(frame)
    return data, VSGPCodec(device="cpu").use_sensors([frame.sensor]).decode(data)


def _slots_of(frame: Frame, data: bytes) -> Slots:
    from lwbench_plugins.vsgp.wire import unpack_body

    payload = Payload.from_bytes(data)
    gp = payload.body[: len(payload.body) - payload.meta["residual"]]
    body = unpack_body(payload.meta["body"], gp, frame.sensor.n_beams, frame.sensor.n_azimuth)
    return scan_slots(frame.points, frame.sensor, body.phase_codes)


def _scores(frame: Frame, points: np.ndarray) -> tuple[float, float]:
    """lwbench's (range RMSD m, coverage)."""
    from lwbench_metrics.ranges import RangeMetric

    from lwbench import CodecKind, Evaluation

    m = RangeMetric().compute(Evaluation(frame, b"", points, CodecKind.REPRESENTATION, {}))
    return float(m["range_rmsd"]), float(m["coverage"])


@pytest.fixture(scope="module")
def tunnel() -> Frame:
    return tunnel_scan(seed=3)


@pytest.mark.parametrize("name", ["room", "hdl32-ring", "exact-duplicates", "tunnel"])
@pytest.mark.parametrize("tau", [0.02, 0.3])
def test_every_kept_return_is_decoded_within_tau(name, tau):
    """The decoder puts its points in slot order (cells row-major, azimuth order within), so
    the i-th decoded point is the i-th kept return's."""
    frame = {**check_frames(), "tunnel": tunnel_scan(seed=1)}[name]
    data, pts = _round_trip(frame, residual=tau, num_inducing=200)
    slots = _slots_of(frame, data)
    assert len(pts) == len(slots.cell)
    err = np.abs(np.linalg.norm(pts.astype(np.float64), axis=1) - slots.ranges)
    assert err.max() <= tau + 1e-4 * frame.sensor.max_range  # float32 points
    kept = len(slots.cell) / np.count_nonzero(np.linalg.norm(frame.points, axis=1) >= frame.sensor.min_range)
    assert kept >= 0.99  # at most MAX_SLOTS returns a cell are kept: these scans hold fewer


@pytest.mark.heavy
@pytest.mark.parametrize("name", ["room", "hdl32-ring"])
def test_rotating_a_scan_moves_the_residual_layers_coverage_by_at_most_001(name):
    frame = check_frames()[name]
    step = frame.sensor.azimuth_step_rad
    covs = [
        _scores(f, _round_trip(f, residual=0.1, num_inducing=300)[1])[1]
        for f in (rotated(frame, k * step) for k in (0.0, 0.13, 0.25, 0.5, 0.77))
    ]
    assert max(covs) - min(covs) <= 0.01, covs
    assert min(covs) >= 0.99, covs


def test_on_a_smooth_tunnel_the_gp_predictor_pays_for_itself(tunnel):
    """The control (``predictor=none``: no surface, every range coded on its own) against the
    GP's prediction at the same threshold: on the paper's kind of scene the GP's payload is
    smaller *and* closer (measured 4.7 vs 6.7 kB, 2.0 vs 2.9 cm)."""
    gp_data, gp_pts = _round_trip(tunnel, residual=0.05, body="q16z")
    ctl_data, ctl_pts = _round_trip(tunnel, residual=0.05, body="q16z", predictor="none")
    assert len(gp_data) < 0.85 * len(ctl_data)
    assert _scores(tunnel, gp_pts)[0] < _scores(tunnel, ctl_pts)[0]


def test_the_residual_layer_lifts_coverage_and_bounds_the_error(tunnel):
    _, plain = _round_trip(tunnel, num_inducing=300)
    _, layered = _round_trip(tunnel, num_inducing=300, residual=0.1)
    assert _scores(tunnel, layered)[1] >= 0.999
    assert _scores(tunnel, layered)[0] < min(0.1, _scores(tunnel, plain)[0])


def test_decode_settings_do_not_change_a_residual_payload(tunnel):
    """upsample / stride / the variance rule are the plain decoder's; a residual payload
    decodes against the default prediction it was measured against."""
    data = VSGPCodec(device="cpu", residual=0.1, num_inducing=300).encode(tunnel)
    sensors = [tunnel.sensor]
    base = VSGPCodec(device="cpu").use_sensors(sensors).decode(data)
    other = VSGPCodec(device="cpu", upsample=2, stride=3, v_floor=0.0).use_sensors(sensors).decode(data)
    assert np.array_equal(base, other)


def _random_slots(sensor, rng) -> Slots:
    counts = np.zeros(sensor.n_rays, np.int64)
    counts[rng.choice(sensor.n_rays, 5000, replace=False)] = rng.integers(1, MAX_SLOTS + 1, 5000)
    cell = np.repeat(np.arange(sensor.n_rays), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(cell)) - np.repeat(starts, counts)
    return Slots(counts, cell, rank, rng.uniform(sensor.min_range, sensor.max_range, len(cell)))


@pytest.mark.parametrize("absolute", [False, True])
def test_pack_and_unpack_agree_exactly(absolute):
    """Residuals to a close prediction of random ranges compress better than the ranges; ranges
    that repeat along the scan, against a prediction that misses them at random, the other way
    round: the encoder sends whichever is smaller, and both decode within TAU."""
    sensor = get_sensor("vlp16")
    rng = np.random.default_rng(0)
    slots = _random_slots(sensor, rng)
    if absolute:
        slots.ranges = np.full(len(slots.cell), 7.3)
        prediction = rng.uniform(sensor.min_range, sensor.max_range, len(slots.cell))
    else:
        prediction = np.clip(slots.ranges + rng.normal(0, 0.3, len(slots.cell)), sensor.min_range, sensor.max_range)
    data, out = pack_residuals(slots, prediction, 0.25, sensor)
    res = unpack_residuals(data, sensor)
    assert res.absolute == absolute
    assert np.array_equal(res.slots.counts, slots.counts) and np.array_equal(res.slots.rank, slots.rank)
    assert res.q == pytest.approx(0.5) and res.tau == pytest.approx(0.25)
    decoded = prediction.copy()
    decoded[res.coded] = (0.0 if absolute else decoded[res.coded]) + res.k * res.q
    assert np.allclose(np.clip(decoded, sensor.min_range, sensor.max_range), out)
    assert np.abs(out - slots.ranges).max() <= 0.25 + 1e-9


def test_the_step_keeps_every_residual_in_16_bits():
    assert residual_step(1e-6, 120.0) * 32767 >= 120.0
    assert residual_step(0.5, 120.0) == 1.0


# -- parameters and bad payloads -----------------------------------------------------------------
def test_parameter_combinations_that_cannot_work_are_refused(tunnel):
    with pytest.raises(ParameterError, match="residual"):
        VSGPCodec(device="cpu", predictor="none").encode(tunnel)
    with pytest.raises(ParameterError, match="num_inducing"):
        VSGPCodec(device="cpu", residual=0.1, bytes=5000).encode(tunnel)


def test_the_control_sends_no_surface(tunnel):
    data, pts = _round_trip(tunnel, residual=0.1, predictor="none")
    assert _scores(tunnel, pts)[1] >= 0.999
    from lwbench_plugins.vsgp.wire import unpack_body

    payload = Payload.from_bytes(data)
    gp = payload.body[: len(payload.body) - payload.meta["residual"]]
    assert unpack_body("float32", gp, 16, 3600).num_inducing == 0


def _with(data: bytes, body: bytes | None = None, **meta) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, {**p.meta, **meta}, p.body if body is None else body, p.pose).to_bytes()


def test_corrupt_residual_sections_raise_payload_error(tunnel):
    data = VSGPCodec(device="cpu", residual=0.1, num_inducing=300).encode(tunnel)
    p = Payload.from_bytes(data)
    n = p.meta["residual"]
    gp, section = p.body[:-n], p.body[-n:]
    head = struct.Struct("<ffB4I")
    tau, q, mode, *lens = head.unpack_from(section)
    flipped = bytearray(section)
    flipped[head.size + 3] ^= 0xFF
    import lzma

    occupied = int(np.count_nonzero(unpack_residuals(section, tunnel.sensor).slots.counts))
    counts = lzma.compress(b"\x03" * occupied, format=lzma.FORMAT_RAW, filters=[{"id": lzma.FILTER_LZMA2}])
    parts = np.cumsum([head.size, *lens])
    occ, bits, values = section[parts[0] : parts[1]], section[parts[2] : parts[3]], section[parts[3] :]
    three_extra = head.pack(tau, q, mode, lens[0], len(counts), lens[2], lens[3]) + occ + counts + bits + values
    cases = [
        _with(data, gp + section[:-3], residual=n - 3),  # truncated section
        _with(data, residual=0),
        _with(data, residual=len(p.body) + 1),
        _with(data, residual=-5),
        _with(data, residual="12"),
        _with(data, gp + head.pack(tau, q, mode, lens[0] + 1, *lens[1:]) + section[head.size :]),  # lengths disagree
        _with(data, gp + head.pack(math.nan, q, mode, *lens) + section[head.size :]),
        _with(data, gp + head.pack(tau, -1.0, mode, *lens) + section[head.size :]),
        _with(data, gp + head.pack(tau, q, 2, *lens) + section[head.size :]),  # no such value mode
        _with(data, gp + bytes(flipped)),
        _with(data, gp + three_extra, residual=len(three_extra)),  # a cell with 4 returns
    ]
    for bad in cases:
        with pytest.raises(PayloadError):
            VSGPCodec(device="cpu").use_sensors([tunnel.sensor]).decode(bad)
