"""Range-image codec: every return kept (overflow, exceptions, offsets), ranges within step/2 and
directions within half an offset step, a grid that follows the scan (a rotation moves nothing),
bounded and checked decoding of every body."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from _scans import rotated
from lwbench_plugins.rangeimage import MAX_RETURNS, RangeImageCodec, pack_image, unpack_image
from lwbench_plugins.rangeimage.bodies import IMAGE_BODIES, _jxl_shape
from lwbench_plugins.rangeimage.grid import coherence, elevation_units
from lwbench_plugins.rangeimage.transform import pack_sparse, unpack_sparse
from scipy.spatial import cKDTree

from lwbench import Evaluation, Frame, ParameterError, Payload, PayloadError, SensorModel, get_sensor
from lwbench.codec import CodecKind
from lwbench.geometry import spherical
from lwbench.registry import get_registry
from lwbench.testing import NO_RETURN, check_frames, room_scan, tunnel_scan


def coverage_and_rmsd(frame: Frame, decoded: np.ndarray) -> tuple[float, float]:
    """The installed range metric (metrics/ranges.py) on one decoded cloud."""
    metric = next(m for m in get_registry().frame_metric_instances() if m.name == "ranges")
    values = metric.compute(Evaluation(frame, b"", decoded, CodecKind.REPRESENTATION, {}))
    return values["coverage"], values["range_rmsd"]


def distinct(points: np.ndarray) -> np.ndarray:
    p = np.ascontiguousarray(points, np.float32)
    _, first = np.unique(p.view(np.dtype((np.void, 12))).ravel(), return_index=True)
    p = p[np.sort(first)]
    return p[np.any(p != 0, axis=1)]


def matched(original: np.ndarray, decoded: np.ndarray, sensor: SensorModel, range_unit: float = 0.05) -> np.ndarray:
    """Each decoded point's original: the nearest in direction, measured in grid spacings
    (azimuth steps, local beam spacings), and range (in ``range_unit``), asserted one-to-one and
    within a quarter of each."""

    def coords(points: np.ndarray) -> np.ndarray:
        r, az, el = spherical(points.astype(np.float64))
        e = sensor.elevations_rad
        row = np.interp(el, e, np.arange(len(e)))
        row = np.where(el > e[-1], len(e) - 1 + (el - e[-1]) / (e[-1] - e[-2]), row)
        row = np.where(el < e[0], (el - e[0]) / (e[1] - e[0]), row)
        col = np.mod((az + math.pi) / sensor.azimuth_step_rad, sensor.n_azimuth)
        return np.stack([col, row + 64, r / range_unit], axis=1)

    box = [sensor.n_azimuth, 4 * len(sensor.elevations_rad) + 256, 1e9]
    tree = cKDTree(coords(original), boxsize=box)
    dist, idx = tree.query(coords(decoded), p=np.inf, distance_upper_bound=0.25)
    assert np.isfinite(dist).all(), f"{int((~np.isfinite(dist)).sum())} decoded points have no original near"
    assert len(np.unique(idx)) == len(idx) == len(original), "decoded and original returns are not one-to-one"
    return original[idx]


def sparse_room(seed: int, sensor: SensorModel | None = None) -> Frame:
    """An off-grid room scan with three of four returns dropped: neighbours are a spacing or
    more apart, so matching decoded to original returns by direction is unambiguous."""
    return room_scan(sensor or get_sensor("vlp16"), seed=seed, dropout=0.75)




def jittered_scan(seed: int = 0, sensor: str = "vlp16") -> Frame:
    """Off-ray jitter, several returns per cell, out-of-range and empty cells."""
    s = get_sensor(sensor)
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.5, 9.5, s.shape)
    ranges[rng.random(s.shape) < 0.2] = 0.0
    pts = s.unproject(ranges).astype(np.float64)
    pts += rng.normal(scale=0.01, size=pts.shape)
    extra = pts[rng.choice(len(pts), 2000)] * rng.uniform(0.9, 1.1, (2000, 1))
    far = rng.normal(size=(50, 3)) * 50
    return Frame(np.concatenate([pts, extra, far]).astype(np.float32), s)


# -- transforms -------------------------------------------------------------------------------
def test_pack_image_round_trip_including_extreme_values() -> None:
    rng = np.random.default_rng(0)
    for width in (2, 4):
        top = (1 << (8 * width)) - 1
        v = rng.integers(0, top + 1, size=(7, 33))
        v[:, 0], v[:, 1], v[0, :] = top, 0, top
        for predict in ("none", "row-delta"):
            for shuffle in (False, True):
                raw = pack_image(v, width, predict, shuffle)
                assert len(raw) == v.size * width
                np.testing.assert_array_equal(unpack_image(raw, v.shape, width, predict, shuffle), v)


def test_pack_sparse_round_trip_with_holes_empty_rows_and_extremes() -> None:
    rng = np.random.default_rng(1)
    occupied = rng.random((9, 40)) < 0.6
    occupied[3] = False  # an empty row
    occupied[5] = True
    n = int(occupied.sum())
    for width in (1, 2, 4):
        bits = 8 * width
        unsigned = rng.integers(0, 1 << bits, n)
        unsigned[:3] = [0, (1 << bits) - 1, 0]
        signed = rng.integers(-(1 << (bits - 1)), 1 << (bits - 1), n)
        for predict in ("none", "row-delta"):
            for shuffle in (False, True):
                raw = pack_sparse(unsigned, occupied, width, predict, shuffle)
                assert len(raw) == n * width
                np.testing.assert_array_equal(unpack_sparse(raw, occupied, width, predict, shuffle), unsigned)
                raw = pack_sparse(signed, occupied, width, predict, shuffle, signed=True)
                np.testing.assert_array_equal(unpack_sparse(raw, occupied, width, predict, shuffle, signed=True),
                                              signed)


# -- every return -------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["room", "exact-duplicates", "hdl32-ring"])
def test_check_frames_keep_every_return_at_coverage_one(name: str) -> None:
    frame = check_frames()[name]
    data = RangeImageCodec().encode(frame)
    decoded = RangeImageCodec().use_sensors([frame.sensor]).decode(data)
    assert len(decoded) == len(distinct(frame.points))  # one point per distinct return
    cov, rmsd = coverage_and_rmsd(frame, decoded)
    # hdl32-ring's sky-facing rings hold returns far outside its beam table, which issue 25's
    # range metric leaves unpaired whatever a codec does; every other return is covered.
    assert cov == 1.0 if name != "hdl32-ring" else cov >= 0.99
    assert rmsd <= 0.01 / math.sqrt(12) * 1.1  # the step's quantization, nothing else
    meta = Payload.from_bytes(data).meta
    if name == "hdl32-ring":
        # Its "no return" filler point (43 deg, where the table's coincident sky-facing beams sit
        # too) and the returns far from every real beam are kept verbatim.
        assert meta["exceptions"] >= 1
        assert (decoded == np.asarray(NO_RETURN, np.float32)).all(axis=1).sum() == 1
    if name == "room":
        # On the sensor's fixed grid, drifting firings share cells (both kept, one as overflow);
        # the grid that follows the firings gives each its own cell.
        fixed = Payload.from_bytes(RangeImageCodec(refine="none").encode(frame)).meta
        assert fixed["overflow"] > 0 and meta["overflow"] == 0


def test_returns_outside_the_sensors_range_window_are_kept() -> None:
    """Issue 25: a later frame's returns beyond the first frame's max range were dropped."""
    frame = sparse_room(seed=2)  # vlp16: 0.1 .. 10 m
    rng = np.random.default_rng(0)
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    beyond = d * rng.uniform(12.0, 250.0, (300, 1))
    near = -d[:50] * 0.05
    points = np.concatenate([frame.points, beyond, near]).astype(np.float32)
    decoded = RangeImageCodec().decode(RangeImageCodec().encode(Frame(points, frame.sensor)))
    assert len(decoded) == len(distinct(points))
    original = matched(distinct(points), decoded, frame.sensor)
    r_dec, r_orig = np.linalg.norm(decoded, axis=1), np.linalg.norm(original, axis=1)
    assert np.abs(r_dec - r_orig).max() <= 0.005 + 1e-5


@pytest.mark.parametrize("step", [0.003, 0.01, 0.05])
def test_ranges_within_half_a_step_and_directions_within_half_an_offset_step(step: float) -> None:
    frame = sparse_room(seed=4)  # off-grid: per-beam phases, elevation jitter, drift
    codec = RangeImageCodec(step=step)
    decoded = codec.decode(codec.encode(frame))
    original = matched(distinct(frame.points), decoded, frame.sensor, range_unit=4 * step)
    r0, az0, el0 = spherical(original.astype(np.float64))
    r1, az1, el1 = spherical(decoded.astype(np.float64))
    err = np.abs(r1 - r0)
    assert err.max() <= step / 2 + 1e-5
    assert err.max() > step / 4  # rounding really happened
    sensor = frame.sensor
    d_az = np.abs((az1 - az0 + math.pi) % (2 * math.pi) - math.pi) / sensor.azimuth_step_rad
    assert d_az.max() <= 0.125 + 1e-3  # offset_step 0.25 spacings -> within 1/8
    rows = np.searchsorted((sensor.elevations_rad[1:] + sensor.elevations_rad[:-1]) / 2, el0)
    d_el = np.abs(el1 - el0) / elevation_units(sensor)[rows]
    assert d_el.max() <= 0.125 + 1e-3


def test_lossless_with_lossless_directions_reproduces_the_points() -> None:
    frame = check_frames()["room"]
    data = RangeImageCodec(mode="lossless", lossless_directions=True).encode(frame)
    decoded = RangeImageCodec().decode(data)
    original = matched(distinct(frame.points), decoded, frame.sensor)
    dist = np.linalg.norm(decoded.astype(np.float64) - original, axis=1)
    # float32 x, y, z: a relative precision of 6e-8; the decode is within two of those.
    assert (dist <= 1.5e-7 * np.linalg.norm(original, axis=1) + 1e-7).all()
    default = RangeImageCodec(mode="lossless").decode(RangeImageCodec(mode="lossless").encode(frame))
    coarse = np.linalg.norm(default.astype(np.float64) - matched(distinct(frame.points), default, frame.sensor), axis=1)
    assert coarse.mean() > 100 * dist.mean()  # what the bytes buy
    assert len(data) > len(RangeImageCodec(mode="lossless").encode(frame))


def test_simulator_scans_decode_on_their_rays_with_free_offsets() -> None:
    """Cell-centre rays (the simulator's case): the lattice is the sensor's, every phase 0.5,
    every offset code 0 -- the decoded directions are the originals'."""
    frame = tunnel_scan(seed=1)
    data = RangeImageCodec().encode(frame)
    meta = Payload.from_bytes(data).meta
    assert meta["columns"] == frame.sensor.n_azimuth and meta["overflow"] == 0 and meta["exceptions"] == 0
    decoded = RangeImageCodec().decode(data)
    original = matched(frame.points, decoded, frame.sensor).astype(np.float64)
    unit = decoded.astype(np.float64) / np.linalg.norm(decoded, axis=1, keepdims=True)
    off_ray = np.linalg.norm(np.cross(original / np.linalg.norm(original, axis=1, keepdims=True), unit), axis=1)
    assert off_ray.max() < 1e-6  # rad: float32 rounding of x, y, z


def test_the_firing_lattice_sets_the_column_count() -> None:
    """A scan fired on 1,790 columns while its sensor model says 1,800: the grid has 1,790."""
    model = SensorModel("model", tuple(np.linspace(-15, 15, 16)), 0.2, 0.1, 50.0, 10.0)
    fired = SensorModel("fired", model.elevations_deg, 360 / 1790, 0.1, 50.0, 10.0)
    frame = room_scan(fired, seed=3, off_grid=True)
    data = RangeImageCodec().encode(Frame(frame.points, model))
    assert Payload.from_bytes(data).meta["columns"] == 1790
    _, az, _ = spherical(frame.points.astype(np.float64))
    rows = np.searchsorted((model.elevations_rad[1:] + model.elevations_rad[:-1]) / 2,
                           spherical(frame.points.astype(np.float64))[2])
    assert coherence(az, rows, 16, 1790) > 0.7 > coherence(az, rows, 16, 1800)
    # Without a lattice (random azimuths) the sensor's own count is kept.
    rng = np.random.default_rng(0)
    pts = frame.points.astype(np.float64)
    r, _, el = spherical(pts)
    a = rng.uniform(-np.pi, np.pi, len(r))
    scattered = np.stack([np.cos(el) * np.cos(a), np.cos(el) * np.sin(a), np.sin(el)], 1) * r[:, None]
    data = RangeImageCodec().encode(Frame(scattered.astype(np.float32), model))
    assert Payload.from_bytes(data).meta["columns"] == 1800


def real_like_scan() -> Frame:
    """A 64-beam scan with no firing lattice at all: each return at a random azimuth, the
    elevation wandering by up to half a beam spacing (as in a deskewed KITTI scan), dual
    returns in a few percent of the firings."""
    s = get_sensor("hdl64e")
    rng = np.random.default_rng(11)
    n = 60000
    rows = rng.integers(0, s.n_beams, n)
    az = rng.uniform(-np.pi, np.pi, n)
    spacing = np.gradient(s.elevations_rad)
    el = s.elevations_rad[rows] + 0.5 * spacing[rows] * np.sin(3 * az + rows)
    r = np.clip(1.7 / np.maximum(np.sin(-el), 0.03), 2.0, 90.0) * rng.uniform(0.97, 1.03, n)
    dual = rng.random(n) < 0.04
    az, el = np.r_[az, az[dual]], np.r_[el, el[dual]]
    r = np.r_[r, r[dual] * rng.uniform(1.2, 2.0, int(dual.sum()))]
    pts = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * r[:, None]
    return Frame(pts.astype(np.float32), s)


@pytest.mark.heavy
@pytest.mark.parametrize("which", ["room", "hdl32-ring", "tunnel", "real-like"])
def test_rotating_the_scan_by_a_fraction_of_a_step_moves_nothing(which: str) -> None:
    """Issue 25: a rotation of the scan before encoding moved coverage from 0.739 to 1.0."""
    frame = {"tunnel": tunnel_scan(seed=2), "real-like": real_like_scan()}.get(which) or check_frames()[which]
    step = frame.sensor.azimuth_step_rad
    results = []
    for fraction in (0.0, 0.13, 0.25, 0.5, 0.77):
        f = rotated(frame, fraction * step)
        data = RangeImageCodec().encode(f)
        results.append((*coverage_and_rmsd(f, RangeImageCodec().use_sensors([f.sensor]).decode(data)), len(data)))
    cov = [c for c, _, _ in results]
    assert max(cov) - min(cov) <= 0.01 and min(cov) >= 0.99
    assert max(r for _, r, _ in results) <= 0.0035
    sizes = [n for _, _, n in results]
    assert max(sizes) <= 1.05 * min(sizes)


def test_fixed_grid_keeps_every_return_too() -> None:
    frame = check_frames()["room"]
    decoded = RangeImageCodec(refine="none").decode(RangeImageCodec(refine="none").encode(frame))
    assert len(decoded) == len(frame.points) and coverage_and_rmsd(frame, decoded)[0] == 1.0


def test_jittered_scan_every_body_round_trips() -> None:
    frame = jittered_scan()
    reference = RangeImageCodec(body="zstd").decode(RangeImageCodec(body="zstd").encode(frame))
    assert len(reference) == len(distinct(frame.points))
    for body in ("lzma", "png", "jpegxl"):  # lossless bodies: the same cloud, bit for bit
        decoded = RangeImageCodec(body=body).decode(RangeImageCodec(body=body).encode(frame))
        np.testing.assert_array_equal(decoded, reference)
    zfp = RangeImageCodec(body="zfp").decode(RangeImageCodec(body="zfp").encode(frame))
    assert zfp.shape == reference.shape
    dr = np.abs(np.linalg.norm(zfp, axis=1) - np.linalg.norm(reference, axis=1))
    assert dr.max() <= 0.005 + 0.005 + 1e-4  # zfp's tolerance (step/2) on top of the quantization
    lossy = RangeImageCodec(body="jpegxl-lossy").decode(RangeImageCodec(body="jpegxl-lossy").encode(frame))
    assert lossy.shape == reference.shape and np.isfinite(lossy).all()


def test_parameters_a_body_cannot_take_are_refused() -> None:
    with pytest.raises(ParameterError):
        RangeImageCodec(body="png", mode="lossless")
    with pytest.raises(ParameterError):
        RangeImageCodec(body="lzma", level=12)
    with pytest.raises(ParameterError):
        RangeImageCodec(body="png", step=0.001).encode(jittered_scan())  # returns beyond 65.5 m


def test_an_accumulated_map_is_refused_with_a_clear_error() -> None:
    s = SensorModel("tiny", tuple(np.linspace(-10, 10, 4)), 10.0, 0.1, 100.0, 10.0)  # 4 x 36 cells
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2000, 3)).astype(np.float32)
    with pytest.raises(ParameterError, match="per cell"):
        RangeImageCodec().encode(Frame(pts, s))
    big = np.repeat(pts[:1], MAX_RETURNS + 1, axis=0)  # refused on its count, before any work
    with pytest.raises(ParameterError, match="not one sweep"):
        RangeImageCodec().encode(Frame(big, get_sensor("vlp16")))


def test_deterministic_and_decoded_by_any_instance() -> None:
    frame = jittered_scan(seed=3)
    a = RangeImageCodec(step=0.02, level=5).encode(frame)
    assert a == RangeImageCodec(step=0.02, level=5).encode(frame)
    np.testing.assert_array_equal(RangeImageCodec(mode="lossless").decode(a), RangeImageCodec(body="png").decode(a))


def test_sensor_travels_in_the_payload() -> None:
    custom = SensorModel("custom", tuple(np.linspace(-10, 10, 8)), 0.5, 0.2, 20.0, 5.0)
    frame = Frame(room_scan(custom).points, custom)
    sensor, image = RangeImageCodec().use_sensors([custom]).decode_image(RangeImageCodec(refine="none").encode(frame))
    assert sensor == custom and image.shape == custom.shape
    preset = RangeImageCodec(sensor="vlp16").encode(frame)
    assert Payload.from_bytes(preset).meta["sensor"] == {"preset": "vlp16"}


def test_empty_scan() -> None:
    frame = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    assert RangeImageCodec().decode(RangeImageCodec().encode(frame)).shape == (0, 3)


# -- corrupt and crafted payloads -----------------------------------------------------------------
def _rewrap(data: bytes, payload_body: bytes | None = None, **meta: object) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, {**p.meta, **meta}, p.body if payload_body is None else payload_body,
                   p.pose).to_bytes()


def _raw_body(data: bytes) -> bytearray:
    import lzma

    from lwbench_plugins.rangeimage.bodies import _lzma_filters

    return bytearray(lzma.decompress(Payload.from_bytes(data).body, format=lzma.FORMAT_RAW, filters=_lzma_filters()))


def _reseal(data: bytes, raw: bytes, **meta: object) -> bytes:
    from lwbench_plugins.rangeimage.bodies import compress

    return _rewrap(data, compress(bytes(raw), "lzma", None), **meta)


def test_corrupt_payloads_raise_payload_error() -> None:
    frame = check_frames()["room"]
    data = RangeImageCodec().encode(frame)
    meta = Payload.from_bytes(data).meta
    body = Payload.from_bytes(data).body
    cases = [
        _rewrap(data, body[: len(body) // 2]),
        _rewrap(data, b"\x00" * 64),
        _rewrap(data, width=4), _rewrap(data, width=3), _rewrap(data, code_width=2),
        _rewrap(data, mode="jpeg"), _rewrap(data, body="brotli"), _rewrap(data, predict="paeth"),
        _rewrap(data, step=-0.01), _rewrap(data, step="1cm"), _rewrap(data, offset_step=0.0),
        _rewrap(data, columns=0), _rewrap(data, columns=10**9), _rewrap(data, columns=True),
        _rewrap(data, cells=meta["cells"] + 1), _rewrap(data, overflow=10**12), _rewrap(data, exceptions=-1),
        _rewrap(data, cells=4 * 10**6, overflow=4 * 10**6),
        _rewrap(data, body="zstd"), _rewrap(data, body="png"), _rewrap(data, body="png", image_bytes=10**9),
        _rewrap(data, sensor={"preset": "nope"}), _rewrap(data, sensor="vlp16"),
        data[:-1], Payload("draco", {}, body).to_bytes(),
    ]
    for bad in cases:
        with pytest.raises(PayloadError):
            RangeImageCodec().decode(bad)


def test_inconsistent_sections_raise_payload_error() -> None:
    frame = check_frames()["room"]
    data = RangeImageCodec(refine="none").encode(frame)  # the fixed grid: overflow returns
    meta = Payload.from_bytes(data).meta
    raw = _raw_body(data)
    n_b = frame.sensor.n_beams
    mask_at = 6 * n_b
    cleared = bytearray(raw)
    cleared[mask_at] ^= 0xFF  # the mask no longer holds `cells` returns
    offset = bytearray(raw)
    offset[2 * n_b : 2 * n_b + 4] = np.array([10**8], "<i4").tobytes()  # 10 rad offset
    for bad in (cleared, offset, raw[:-1]):
        with pytest.raises(PayloadError):
            RangeImageCodec().decode(_reseal(data, bad))
    # An overflow return in a cell with no first return.
    n_cells = n_b * meta["columns"]
    mask = np.unpackbits(np.frombuffer(bytes(raw[mask_at : mask_at + (n_cells + 7) // 8]), np.uint8))[:n_cells]
    empty = int(np.flatnonzero(mask == 0)[0])
    sizes = [6 * n_b, (n_cells + 7) // 8, 2 * meta["cells"], 2 * meta["cells"]]
    at = sum(sizes)
    ov = bytearray(raw)
    n_ov = meta["overflow"]
    first = np.array([empty], "<u4").view(np.uint8)
    for k in range(4):  # byte planes: byte k of the first overflow cell step
        ov[at + k * n_ov] = first[k]
    with pytest.raises(PayloadError):
        RangeImageCodec().decode(_reseal(data, ov))


def test_image_headers_are_checked_before_the_library_sees_them(monkeypatch: pytest.MonkeyPatch) -> None:
    import imagecodecs

    frame = check_frames()["room"]
    for body in IMAGE_BODIES:
        data = RangeImageCodec(body=body).encode(frame)
        p = Payload.from_bytes(data)
        n = p.meta["image_bytes"]
        image, side = p.body[:n], p.body[n:]
        if body == "png":  # IHDR declaring 2**31 x 2**31 pixels
            bad = image[:16] + (2**31).to_bytes(4, "big") * 2 + image[24:]
        elif body == "zfp":  # another mode word (a fixed-rate stream)
            bad = bytes(imagecodecs.zfp_encode(np.zeros((16, 16), np.float32), 4, mode="rate", header=False)) + image
        else:  # a JPEG XL image of another size
            bad = bytes(imagecodecs.jpegxl_encode(np.zeros((4096, 4096), np.uint16), lossless=True, effort=1))
        called = []
        for name in ("png_decode", "jpegxl_decode", "zfp_decode"):
            monkeypatch.setattr(imagecodecs, name, lambda *a, _n=name, _c=called, **k: _c.append(_n))
        with pytest.raises(PayloadError):
            RangeImageCodec().decode(_rewrap(data, bad + side, image_bytes=len(bad)))
        assert not called, f"{body}: the library was called on a header that does not fit the grid"
        monkeypatch.undo()


def test_jpeg_xl_size_header_reads_every_form() -> None:
    import imagecodecs

    rng = np.random.default_rng(0)
    for shape in [(16, 3600), (64, 2086), (128, 1024), (8, 8), (61, 1800), (1, 720), (256, 16384), (3, 7)]:
        a = rng.integers(0, 60000, shape).astype(np.uint16)
        assert _jxl_shape(bytes(imagecodecs.jpegxl_encode(a, lossless=True, effort=1))) == shape
        assert _jxl_shape(bytes(imagecodecs.jpegxl_encode(a.astype(np.uint8), lossless=True, effort=1))) == shape


# -- real scans ---------------------------------------------------------------------------------
def ouster_sensor(folder: Path) -> SensorModel:
    meta = json.loads((folder / "sensor_metadata.json").read_text())
    return SensorModel("os1-128-seq3", tuple(meta["beam_altitude_angles"]), 360 / 1024, 0.3, 120.0, 10.0)


def test_real_ouster_scan_every_return(real_data: Path) -> None:
    ouster = real_data / "ouster_os1-128_seq3"
    pts = np.fromfile(ouster / "000000.bin", dtype=np.float32).reshape(-1, 4)[:, :3]
    frame = Frame(pts, ouster_sensor(ouster))
    assert (np.linalg.norm(pts, axis=1) > frame.sensor.max_range).any()  # returns beyond 120 m
    data = RangeImageCodec().encode(frame)
    assert Payload.from_bytes(data).meta["columns"] == 1024  # the 1024x10 mode's lattice
    decoded = RangeImageCodec().use_sensors([frame.sensor]).decode(data)
    assert len(decoded) == len(distinct(pts))
    cov, rmsd = coverage_and_rmsd(frame, decoded)
    assert cov == 1.0 and rmsd < 0.0031
    # Measured 13.2x at 1 cm (version 3, which dropped 2 % of the returns: 11.4x).
    assert frame.raw_bytes / len(data) > 12


def real_folders() -> list[str]:
    from _real import real_data_dir

    root = real_data_dir()
    return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else ["(absent)"]


@pytest.mark.heavy
@pytest.mark.parametrize("folder", real_folders())
def test_every_real_folder_is_covered_at_the_steps_error(real_data: Path, folder: str) -> None:
    """Issue 24's bar on each shared real folder (first frame, the loader's sensor model, the
    codec's defaults): coverage >= 0.99 and range RMSD <= 1 cm + the step's quantization."""
    from lwbench.run.plan import resolve_dataset

    registry = get_registry()
    spec = resolve_dataset(registry, str(real_data / folder), {}, 0)
    frame = registry.dataset(spec.name)(**spec.params)[0]
    decoded = RangeImageCodec().use_sensors([frame.sensor]).decode(RangeImageCodec().encode(frame))
    assert len(decoded) == len(distinct(frame.points))
    cov, rmsd = coverage_and_rmsd(frame, decoded)
    assert cov >= 0.99 and rmsd <= 0.01 + 0.01 / math.sqrt(12)
