"""A headerless ``.bin`` is read with the record size its geometry says, or refused: never a
misread (issue 25: KITTI frame 0 with intensity 0, shuffled, read as 166,224 points of 12 bytes,
z from -77 to +77 m)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from _real import kitti_frame0
from _scans import spinning_scan, street_scan
from lwbench_plugins.files import KittiDataset, PointFileDataset

from lwbench import SensorModel, get_sensor
from lwbench.errors import DataFormatError
from lwbench.io import read_kitti_bin
from lwbench.testing import hdl32_ring_scan, room_scan

HDL64E_10HZ = SensorModel("hdl64e-10hz", get_sensor("hdl64e").elevations_deg, 360 / 2083, 0.9, 120.0, 10.0)


def _kitti_like(n_multiple_of: int = 3) -> np.ndarray:
    """An HDL-64E street scan as KITTI's (lasers 0.2 m above the frame's origin), its point
    count a multiple of 3, so its x,y,z,intensity bytes are also a whole number of 12-byte records."""
    pts = street_scan(HDL64E_10HZ, laser_height_m=0.2, table_jitter_deg=0.1)
    return pts[: len(pts) - len(pts) % n_multiple_of]


def test_a_shuffled_zero_intensity_kitti_scan_reads_as_its_points(tmp_path):
    pts = _kitti_like()
    pts = pts[np.random.default_rng(0).permutation(len(pts))]
    np.column_stack([pts, np.zeros(len(pts), np.float32)]).astype("<f4").tofile(tmp_path / "000000.bin")
    assert (16 * len(pts)) % 12 == 0  # the size also reads as x,y,z: 4/3 as many "points"
    scan = read_kitti_bin(tmp_path / "000000.bin")
    np.testing.assert_array_equal(scan.points, pts)
    assert scan.intensity is not None and not scan.intensity.any()


@pytest.mark.heavy
def test_the_real_kitti_frame_written_with_zero_intensity_and_shuffled_reads_right(real_data, tmp_path):
    pts = read_kitti_bin(kitti_frame0()).points
    assert len(pts) == 124_668
    shuffled = pts[np.random.default_rng(0).permutation(len(pts))]
    np.column_stack([shuffled, np.zeros(len(pts), np.float32)]).astype("<f4").tofile(tmp_path / "000000.bin")
    scan = read_kitti_bin(tmp_path / "000000.bin")
    assert len(scan.points) == 124_668 and scan.intensity is not None
    np.testing.assert_array_equal(scan.points, shuffled)
    assert KittiDataset(path=str(tmp_path))[0].points.shape == (124_668, 3)


def _scans() -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """Scans of several sensors with the intensity columns real files have."""
    rng = np.random.default_rng(1)
    room = room_scan(get_sensor("vlp16"), seed=2).points
    ring = hdl32_ring_scan()
    os1 = spinning_scan("os1-128", order="ring", dropout=0.3)
    return {
        "kitti-like": (_kitti_like(1), None),
        "room": (room, rng.uniform(0, 1, len(room)).astype(np.float32)),
        "hdl32 ring": (ring.points, ring.intensity),
        "os1 reflectivity": (os1, rng.integers(0, 256, len(os1)).astype(np.float32)),
    }


@pytest.mark.heavy
@pytest.mark.parametrize("name", list(_scans()))
def test_every_bin_reading_is_right_or_an_error(tmp_path, name):
    pts, inten = _scans()[name]
    rng = np.random.default_rng(3)
    layouts = ("xyz", "xyzi-zero", "xyzi", "xyzir") if inten is not None else ("xyz", "xyzi-zero")
    for layout, shuffle, trim in itertools.product(layouts, (False, True), range(3)):
        n = len(pts) - trim  # point counts that make each size fit one, two or three record sizes
        order = rng.permutation(n) if shuffle else np.arange(n)
        p = pts[:n][order]
        columns = [p]
        if layout != "xyz":
            columns.append(np.zeros(n, np.float32) if layout == "xyzi-zero" else inten[:n][order])
        if layout == "xyzir":
            columns.append(np.arange(n, dtype=np.float32) % 32)
        path = tmp_path / f"{layout}-{shuffle}-{trim}.bin"
        np.column_stack(columns).astype("<f4").tofile(path)
        try:
            scan = read_kitti_bin(path)
        except DataFormatError as exc:
            assert "fields=xyz|xyzi" in str(exc), exc
            continue
        np.testing.assert_array_equal(scan.points, p[np.any(p != 0, axis=1)], err_msg=f"{name} {path.name}")


def test_an_undecidable_size_names_fields_and_fields_reads_it(tmp_path):
    # A uniform cube of x, y, z and an intensity drawn the same way: no reading looks like a scan
    # more than another -- an error that names the parameter, and the parameter reads it.
    rows = np.random.default_rng(0).uniform(0, 5, (3000, 4)).astype("<f4")  # 48,000 B: 3,000 x 16 or 4,000 x 12
    rows.tofile(tmp_path / "000000.bin")
    with pytest.raises(DataFormatError, match=r"no reading looks like a scan.*fields=xyz\|xyzi") as err:
        read_kitti_bin(tmp_path / "000000.bin")
    assert "\n" not in str(err.value)
    assert len(read_kitti_bin(tmp_path / "000000.bin", "xyzi").points) == 3000
    assert len(read_kitti_bin(tmp_path / "000000.bin", "xyz").points) == 4000
    ds = KittiDataset(path=str(tmp_path), fields="xyzi", sensor="hdl64e")
    assert len(ds[0]) == 3000
    assert len(PointFileDataset(path=str(tmp_path / "000000.bin"), fields="xyz", sensor="hdl64e")[0]) == 4000
    with pytest.raises(DataFormatError, match="fifth column is not a ring index"):
        read_kitti_bin(tmp_path / "000000.bin", "xyzir")


def test_a_reading_whose_order_contradicts_its_geometry_is_an_error(tmp_path):
    # 12-byte points in scan order whose every fourth value is non-negative: the geometry picks
    # neither, or the order check catches the pick -- never a silent misread.
    pts = np.abs(spinning_scan("vlp16", order="ring")[:4800])
    pts.astype("<f4").tofile(tmp_path / "a.bin")
    try:
        scan = read_kitti_bin(tmp_path / "a.bin")
    except DataFormatError as exc:
        assert "fields=" in str(exc)
    else:
        np.testing.assert_array_equal(scan.points, pts)
