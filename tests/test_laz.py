"""laz codec: lossless at its scale, intensity kept, a real LAS 1.4 file, bounded decoding."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
import pytest
from lwbench_metrics.ranges import RangeMetric
from lwbench_plugins.laz import LazCodec, check_las, read_laz

from lwbench import CodecKind, Evaluation, Frame, Payload, PayloadError, get_sensor
from lwbench.testing import hdl32_ring_scan, room_scan


def _room() -> Frame:
    return room_scan(get_sensor("vlp16"), seed=4, dropout=0.02)


def _range_values(frame: Frame, data: bytes, decoded: np.ndarray) -> dict:
    return RangeMetric().compute(Evaluation(frame, data, decoded, CodecKind.REPRESENTATION, {}))


@pytest.mark.parametrize("scale", [0.001, 0.01, 0.0001])
def test_lossless_at_its_scale(scale: float) -> None:
    frame = _room()
    data = LazCodec(scale=scale).encode(frame)
    decoded = LazCodec().decode(data)  # the decoder reads the scale from the LAS header
    assert decoded.shape == frame.points.shape  # every return, in the scan's order
    err = np.abs(decoded.astype(np.float64) - frame.points)
    assert err.max() <= scale / 2 + 1e-6
    if scale >= 0.001:
        assert err.max() > scale / 4  # the grid really is that coarse
    values = _range_values(frame, data, decoded)
    assert values["range_rmsd"] <= np.sqrt(3) / 2 * scale
    # Coverage pairs returns within half a beam/azimuth cell of their direction: 1 while the
    # scale is small against a cell at the nearest range (VLP-16: 0.2 deg, 1 cm at the room's
    # 3 m); at a 1 cm scale half the step moves a return across half a cell (measured 0.67).
    if scale <= 0.001:
        assert values["coverage"] == 1.0


def test_coarser_scale_is_smaller() -> None:
    frame = _room()
    sizes = [len(LazCodec(scale=s).encode(frame)) for s in (0.0001, 0.001, 0.01)]
    assert sizes[0] > sizes[1] > sizes[2]


def test_the_body_is_a_las_14_file_any_reader_opens() -> None:
    import laspy

    frame = _room()
    body = Payload.from_bytes(LazCodec().encode(frame)).body
    las = laspy.read(io.BytesIO(body))
    assert (las.header.version.major, las.header.version.minor) == (1, 4)
    assert las.header.point_format.id == 6 and las.header.are_points_compressed
    assert las.header.point_count == len(frame)
    np.testing.assert_allclose(las.header.scales, 0.001)


def test_intensity_is_kept() -> None:
    frame = _room()
    n = len(frame)
    # Integer intensities (Ouster reflectivity, nuScenes) pass unchanged.
    counts = Frame(frame.points, frame.sensor, intensity=np.arange(n, dtype=np.float32) % 256)
    data = LazCodec().encode(counts)
    _, got = read_laz(Payload.from_bytes(data).body, n)
    np.testing.assert_array_equal(got, np.arange(n) % 256)
    assert Payload.from_bytes(data).meta["intensity_scale"] == 1.0
    # KITTI's reflectance in [0, 1] is normalized to 16 bits, as LAS asks; the factor travels.
    refl = Frame(frame.points, frame.sensor, intensity=np.linspace(0, 1, n, dtype=np.float32))
    data = LazCodec().encode(refl)
    factor = Payload.from_bytes(data).meta["intensity_scale"]
    _, got = read_laz(Payload.from_bytes(data).body, n)
    assert factor == 65535.0
    np.testing.assert_allclose(got / factor, refl.intensity, atol=1 / 65535)
    # intensity=false sends none; the bytes shrink.
    without = LazCodec(intensity=False).encode(counts)
    assert not read_laz(Payload.from_bytes(without).body, n)[1].any()
    assert len(without) < len(LazCodec().encode(counts))


def test_ring_scan_with_no_return_copies() -> None:
    frame = hdl32_ring_scan()
    decoded = LazCodec().decode(LazCodec().encode(frame))
    assert len(decoded) == len(frame)  # exact copies are kept: LAS is a list of records


def _rewrap(data: bytes, body: bytes, **meta: object) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, {**p.meta, **meta}, body, p.pose).to_bytes()


def test_counts_are_checked_before_laspy_allocates(monkeypatch) -> None:
    import laspy

    frame = _room()
    data = LazCodec().encode(frame)
    body = bytearray(Payload.from_bytes(data).body)
    n = len(frame)

    def never(*args, **kwargs):
        raise AssertionError("laspy was called on a body the checks must refuse")

    monkeypatch.setattr(laspy, "read", never)
    big = 40_000_000
    grown = bytearray(body)
    struct.pack_into("<Q", grown, 247, big)  # the LAS 1.4 point count
    cases = [
        (bytes(grown), {"n": big}),  # more points than MAX_POINTS, and than the bytes pay for
        (bytes(grown), {}),  # the LAS count disagrees with the lwbench header
        (bytes(body[:400]), {}),  # truncated inside the VLR
        (bytes(body[: len(body) // 2]), {}),  # chunk table offset past the end
    ]
    point_data = struct.unpack_from("<I", body, 96)[0]
    layer = bytearray(body)
    struct.pack_into("<I", layer, point_data + 8 + 30 + 4, 0xFFFFFFFF)  # a layer of 4 GB (lazrs aborted)
    cases.append((bytes(layer), {}))
    count = bytearray(body)
    struct.pack_into("<I", count, point_data + 8 + 30, n + 1)  # a chunk claiming one point more
    cases.append((bytes(count), {}))
    fmt = bytearray(body)
    fmt[104] = 7 | 0x80  # another point format
    cases.append((bytes(fmt), {}))
    for bad, meta in cases:
        with pytest.raises(PayloadError):
            LazCodec().decode(_rewrap(data, bad, **meta))


def test_degenerate_and_huge_scans_are_refused_on_encode_with_the_reason() -> None:
    sensor = get_sensor("vlp16")
    same = Frame(np.tile(np.float32([[1.0, 2.0, 0.5]]), (100_000, 1)), sensor)
    with pytest.raises(ValueError, match="bits per point|needs"):
        LazCodec().encode(same)  # 0.12 bits per point: below what the decoder accepts
    far = Frame(np.float32([[3e6, 0.0, 0.0], [1.0, 1.0, 1.0]]), sensor)
    with pytest.raises(ValueError, match="int32"):
        LazCodec().encode(far)
    assert len(LazCodec(scale=1.0).decode(LazCodec(scale=1.0).encode(far))) == 2


def test_empty_scan_round_trips() -> None:
    empty = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    data = LazCodec().encode(empty)
    check_las(Payload.from_bytes(data).body, 0)
    assert LazCodec().decode(data).shape == (0, 3)


def test_real_kitti_frame_ratio_error_coverage(real_data: Path) -> None:
    """The issue's bar: ratio >= 2 at range RMSD <= 1 mm, coverage >= 0.99 (measured: 5.26x,
    0.29 mm, 1.0 -- docs/codecs.md)."""
    pts = np.fromfile(real_data / "kitti00_frames0-1" / "000000.bin", dtype=np.float32).reshape(-1, 3)
    frame = Frame(pts, get_sensor("hdl64e"))
    data = LazCodec().encode(frame)
    values = _range_values(frame, data, LazCodec().decode(data))
    assert frame.raw_bytes / len(data) >= 2
    assert values["range_rmsd"] <= 0.001 and values["coverage"] >= 0.99
