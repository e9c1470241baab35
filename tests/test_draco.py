"""Draco codec: round trip within its quantization grid, pinned parameters, corrupt bodies,
scans holding duplicate points."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lwbench_plugins.draco import DracoCodec, distinct_points, quantization_step
from scipy.spatial import cKDTree

from lwbench import Frame, Payload, PayloadError, get_sensor


def scan(n: int = 20_000, seed: int = 0) -> Frame:
    """A street-sized synthetic cloud: wide in x/y, shallow in z, like a spinning LiDAR's."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-60, -60, -3], [60, 60, 5], size=(n, 3)).astype(np.float32)
    return Frame(pts, get_sensor("hdl64e"))


def assert_on_grid(original: np.ndarray, decoded: np.ndarray, step: float) -> None:
    """Same count, and both directions within step/2 per coordinate (Chebyshev distance).

    Draco dequantizes in float32, so allow a few float32 ulps at the scan's largest coordinate.
    """
    assert decoded.shape == original.shape
    tol = step / 2 + 4 * float(np.spacing(np.abs(original).max()))
    d_fwd, _ = cKDTree(original).query(decoded, p=np.inf)
    d_bwd, _ = cKDTree(decoded).query(original, p=np.inf)
    assert d_fwd.max() <= tol, (d_fwd.max(), step / 2)
    assert d_bwd.max() <= tol, (d_bwd.max(), step / 2)


@pytest.mark.parametrize("bits", [8, 11, 14])
def test_round_trip_within_quantization_step(bits: int) -> None:
    frame = scan()
    data = DracoCodec(quantization_bits=bits).encode(frame)
    decoded = DracoCodec(quantization_bits=bits).decode(data)
    step = quantization_step(frame.points, bits)
    assert_on_grid(frame.points, decoded, step)
    # A coarser grid must not be exact: the check above has teeth only if errors exist.
    if bits <= 11:
        assert cKDTree(frame.points).query(decoded)[0].max() > step / 10


@pytest.mark.parametrize("level", [0, 1, 10])
def test_every_declared_compression_level_decodes(level: int) -> None:
    """Level 0 makes Draco code sequentially, which the decoder's pre-check refused (issue 33):
    an encoder must never write what its own decoder refuses."""
    frame = scan()
    data = DracoCodec(compression_level=level).encode(frame)
    decoded = DracoCodec(compression_level=level).decode(data)
    assert_on_grid(frame.points, decoded, quantization_step(frame.points, 14))


def test_explicit_quantization_range_sets_the_step() -> None:
    frame = scan(5_000)
    codec = DracoCodec(quantization_bits=12, quantization_range=200.0)
    decoded = DracoCodec().decode(codec.encode(frame))
    assert_on_grid(frame.points, decoded, 200.0 / 4095)
    with pytest.raises(ValueError):
        DracoCodec(quantization_range=10.0).encode(frame)  # the scan is 120 m wide


def test_parameters_are_pinned_and_change_the_bytes() -> None:
    assert DracoCodec().config["quantization_bits"] == 14
    assert DracoCodec().config["compression_level"] == 7
    frame = scan()
    sizes = [len(DracoCodec(quantization_bits=b).encode(frame)) for b in (10, 12, 14)]
    assert sizes[0] < sizes[1] < sizes[2]
    assert len(DracoCodec(compression_level=10).encode(frame)) < len(
        DracoCodec(compression_level=0).encode(frame)
    )


def test_decoding_needs_only_the_bytes_and_is_deterministic() -> None:
    frame = scan()
    a = DracoCodec(quantization_bits=12).encode(frame)
    b = DracoCodec(quantization_bits=12).encode(frame)
    assert a == b
    # The decoder's own parameters are irrelevant: it reads the bytes.
    np.testing.assert_array_equal(DracoCodec(quantization_bits=3).decode(a), DracoCodec().decode(a))


def test_empty_and_single_point_scans() -> None:
    empty = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    assert DracoCodec().decode(DracoCodec().encode(empty)).shape == (0, 3)
    one = Frame(np.array([[1.0, 2.0, 3.0]], np.float32), get_sensor("vlp16"))
    np.testing.assert_allclose(DracoCodec().decode(DracoCodec().encode(one)), one.points, atol=1e-6)


def _rewrap(data: bytes, body: bytes, **meta_changes: object) -> bytes:
    """A payload with a valid header and checksum around a different body: only the Draco
    parser can catch what is wrong."""
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, {**p.meta, **meta_changes}, body, p.pose).to_bytes()


def test_corrupt_bodies_raise_payload_error() -> None:
    frame = scan(3_000)
    data = DracoCodec().encode(frame)
    body = Payload.from_bytes(data).body
    rng = np.random.default_rng(1)
    flipped = bytearray(body)
    flipped[: len(flipped) // 2] = rng.integers(0, 256, len(flipped) // 2, dtype=np.uint8).tobytes()
    bad = [
        body[: len(body) // 2],  # truncated
        b"",  # missing
        b"DRACO" + bytes(40),  # looks like a header, is not
        bytes(flipped),  # garbage
    ]
    codec = DracoCodec()
    for b in bad:
        with pytest.raises(PayloadError):
            codec.decode(_rewrap(data, b))
    with pytest.raises(PayloadError):
        codec.decode(_rewrap(data, body, n=len(frame) + 1))  # count disagrees with the header
    with pytest.raises(PayloadError):
        codec.decode(data[:-5])  # truncated payload: the shared checksum catches it
    with pytest.raises(PayloadError):
        codec.decode(Payload("raw", {}, body).to_bytes())  # another codec's payload


def test_real_kitti_scan_ratio_and_error(real_data: Path) -> None:
    pts = np.fromfile(real_data / "kitti00_frames0-1" / "000000.bin", dtype=np.float32).reshape(-1, 3)
    frame = Frame(pts, get_sensor("hdl64e"))
    data = DracoCodec(quantization_bits=11).encode(frame)
    decoded = DracoCodec().decode(data)
    assert_on_grid(pts, decoded, quantization_step(pts, 11))
    # Measured 19-22x at 11 bits (docs/codecs.md); well above 10x whatever the Draco build.
    assert frame.raw_bytes / len(data) > 10


def _rows(a: np.ndarray) -> set[bytes]:
    return {r.tobytes() for r in np.ascontiguousarray(a, dtype=np.float32)}


def test_distinct_points_is_the_first_of_each_bitwise_group() -> None:
    rng = np.random.default_rng(4)
    base = rng.uniform(-50, 50, (500, 3)).astype(np.float32)
    base[:50, 0] = base[50:100, 0]  # equal x, different y: only full rows count
    base[100:150, :2] = base[150:200, :2]  # equal x and y, different z
    pts = np.concatenate([base, base[rng.integers(0, 500, 300)], [[0, 0, 0], [-0.0, 0, 0]]]).astype(np.float32)
    pts = pts[rng.permutation(len(pts))]
    _, first = np.unique(pts.view(np.dtype((np.void, 12))).ravel(), return_index=True)
    np.testing.assert_array_equal(distinct_points(pts), np.sort(first))
    assert len(distinct_points(pts)) == 502  # -0.0 and 0.0 differ bit for bit, as for Draco
    np.testing.assert_array_equal(distinct_points(base), np.arange(500))
    assert len(distinct_points(np.zeros((0, 3), np.float32))) == 0


def test_exact_duplicate_points_all_come_back() -> None:
    # nuScenes-like: a quarter of the returns are exact copies of others (issue 11: a frame
    # of 34,752 points decoded to 25,532; issue 22: every return must come back).
    frame = scan(8_000, seed=5)
    rng = np.random.default_rng(5)
    copies = frame.points[rng.integers(0, len(frame), 2_700)]
    dup = Frame(np.concatenate([frame.points, copies])[rng.permutation(len(frame) + 2_700)], frame.sensor)
    data = DracoCodec().encode(dup)
    decoded = DracoCodec().decode(data)
    meta = Payload.from_bytes(data).meta
    assert meta["n"] == len(decoded) == len(dup) and meta["distinct"] == len(_rows(dup.points)) == len(frame)
    assert_on_grid(dup.points, decoded, quantization_step(dup.points, 14))
    # The copies come back as copies: as many repeated rows as the scan had.
    assert len(decoded) - len(_rows(decoded)) >= len(dup) - len(frame)
    # A scan without copies is coded as by v2: no attribute, no "distinct" field.
    plain = DracoCodec().encode(frame)
    assert "distinct" not in Payload.from_bytes(plain).meta
    assert len(data) > len(plain)  # the copy counts are paid for
    all_same = Frame(np.tile(np.float32([[1.5, -2.0, 0.25]]), (100, 1)), frame.sensor)
    np.testing.assert_allclose(DracoCodec().decode(DracoCodec().encode(all_same)), all_same.points, atol=1e-6)


def test_copy_counts_that_do_not_add_up_are_refused() -> None:
    frame = scan(2_000, seed=7)
    dup = Frame(np.concatenate([frame.points, frame.points[:300]]), frame.sensor)
    data = DracoCodec().encode(dup)
    body = Payload.from_bytes(data).body
    codec = DracoCodec()
    for change in ({"n": len(dup) + 1}, {"n": len(dup) - 1}, {"distinct": len(frame) - 1}, {"distinct": len(dup)}):
        with pytest.raises(PayloadError):
            codec.decode(_rewrap(data, body, **change))
    no_counts = Payload.from_bytes(DracoCodec().encode(frame)).body  # the distinct points, no attribute
    with pytest.raises(PayloadError, match="copy counts"):
        codec.decode(_rewrap(data, no_counts))


def test_dual_returns_in_one_cell_keep_full_coverage() -> None:
    """A generated scan with two returns in every range-image cell: every firing of an off-grid
    room scan has a second return three 14-bit steps behind the first, as a dual-return sensor
    writes on a thin surface. Draco keeps both; the range metric pairs both. (Returns closer than
    a step decode to one point twice, and the range metric counts exact copies once, on both
    clouds alike: such a pair is one return after quantization.)"""
    from lwbench_metrics.ranges import RangeMetric

    from lwbench import CodecKind, Evaluation
    from lwbench.testing import room_scan

    room = room_scan(get_sensor("vlp16"), seed=3)
    step = quantization_step(room.points, 14)
    ray = room.points / np.linalg.norm(room.points, axis=1, keepdims=True)
    second = (room.points + 3 * step * ray).astype(np.float32)
    dual = Frame(np.concatenate([room.points, second]), room.sensor)
    assert len(distinct_points(dual.points)) == len(dual)
    data = DracoCodec().encode(dual)
    decoded = DracoCodec().decode(data)
    assert len(decoded) == len(dual)
    values = RangeMetric().compute(Evaluation(dual, data, decoded, CodecKind.REPRESENTATION, {}))
    assert values["coverage"] == 1.0
    assert values["range_rmsd"] < quantization_step(dual.points, 14)


def test_near_duplicates_are_kept_even_in_one_quantization_cell() -> None:
    """Draco merges bit-equal input points only: points one ulp apart, or a tenth of a grid
    step apart (so they quantize to the same cell and decode to the same point), all come
    back. If a DracoPy release started merging after quantization, this fails rather than
    the header's count silently disagreeing."""
    frame = scan(3_000, seed=6)
    step = quantization_step(frame.points, 11)
    ulp = np.nextafter(frame.points[:500], np.float32(np.inf))
    near = frame.points[500:1000] + np.float32(step / 10)
    pts = np.concatenate([frame.points, ulp, near]).astype(np.float32)
    assert len(distinct_points(pts)) == len(pts)
    data = DracoCodec(quantization_bits=11).encode(Frame(pts, frame.sensor))
    decoded = DracoCodec().decode(data)
    assert len(decoded) == len(pts) == Payload.from_bytes(data).meta["n"]
    assert len(_rows(decoded)) < len(decoded)  # some really did land in one cell
    assert_on_grid(pts, decoded, step)


def test_a_count_beyond_what_the_codec_writes_is_refused_before_dracopy_allocates() -> None:
    """Issue 33, item 14: DracoPy allocates for the count in Draco's header before it reads the
    body (a 65 kB body declaring 2^24 points peaked at 384 MB). Counts above MAX_DISTINCT are
    refused from the header alone; the encoder refuses to write them."""
    from lwbench_plugins.draco import _DRACO_HEAD, MAX_DISTINCT

    frame = scan(2_000)
    data = DracoCodec().encode(frame)
    body = bytearray(Payload.from_bytes(data).body)
    fields = list(_DRACO_HEAD.unpack_from(body))
    fields[-1] = 1 << 24
    _DRACO_HEAD.pack_into(body, 0, *fields)
    with pytest.raises(PayloadError, match="distinct points, more than"):
        DracoCodec().decode(_rewrap(data, bytes(body), n=1 << 24))
    x = np.arange(MAX_DISTINCT + 1, dtype=np.float32) * np.float32(1e-3)  # all distinct in float32
    big = Frame(np.repeat(x[:, None], 3, axis=1), get_sensor("hdl64e"))
    with pytest.raises(ValueError, match="at most"):
        DracoCodec().encode(big)
