"""Scan file formats: each is read as what it is, or refused with a clear error -- never a
silently different scan (wrong point count, columns shifted into coordinates, a shorter cloud)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _scans import spinning_scan

from lwbench import get_sensor
from lwbench.errors import DataFormatError
from lwbench.io import read_kitti_bin, read_point_file, read_sensor_file, read_xyz

NUSCENES_NAME = "n008-2018-08-01-15-16-36-0400__LIDAR_TOP__1533151603547590.pcd.bin"


def _nuscenes_points(n_az: int = 250) -> np.ndarray:
    """x, y, z, intensity (0-255), ring (0-31) float32 rows, like nuScenes LIDAR_TOP."""
    from lwbench import SensorModel

    s = SensorModel("hdl32", tuple(np.linspace(-30.67, 10.67, 32)), 360 / n_az, 0.5, 80.0, 20.0)
    pts = spinning_scan(s, order="firing")
    ring = np.tile(np.arange(32), n_az).astype(np.float32)
    inten = np.random.default_rng(0).integers(0, 256, len(pts)).astype(np.float32)
    return np.column_stack([pts, inten, ring]).astype("<f4")


def test_nuscenes_pcd_bin_is_five_floats_per_point_with_ring(tmp_path):
    rows = _nuscenes_points()  # 8,000 points: 160,000 bytes, also a whole number of 16-byte records
    path = tmp_path / NUSCENES_NAME
    rows.tofile(path)
    assert (len(rows) * 20) % 16 == 0  # read as KITTI x,y,z,i it would be 10,000 points
    scan = read_point_file(path)
    assert len(scan.points) == len(rows) == 8000
    np.testing.assert_array_equal(scan.points, rows[:, :3])
    np.testing.assert_array_equal(scan.intensity, rows[:, 3])
    np.testing.assert_array_equal(scan.ring, rows[:, 4].astype(np.uint16))
    assert np.linalg.norm(scan.points, axis=1).max() <= 80.0


def test_a_renamed_nuscenes_file_is_recognised_by_its_ring_column(tmp_path):
    rows = _nuscenes_points()
    rows.tofile(tmp_path / "000000.bin")
    scan = read_kitti_bin(tmp_path / "000000.bin")
    assert len(scan.points) == 8000 and scan.ring is not None and scan.ring.max() == 31


def test_a_pcd_bin_that_is_not_nuscenes_is_an_error(tmp_path):
    rows = _nuscenes_points()
    rows[1:, :4].tofile(tmp_path / "a.pcd.bin")  # 7,999 x 16 bytes: not a whole number of 20
    with pytest.raises(DataFormatError, match="N x 20"):
        read_kitti_bin(tmp_path / "a.pcd.bin")
    rows[:, 4] = 0.5  # 5 columns, but the fifth is no ring index
    rows.tofile(tmp_path / "b.pcd.bin")
    with pytest.raises(DataFormatError, match="not a ring index"):
        read_kitti_bin(tmp_path / "b.pcd.bin")


@pytest.mark.parametrize("name", ["empty.bin", "empty.pcd", "empty.ply", "empty.xyz"])
def test_an_empty_file_is_an_error_not_an_empty_scan(tmp_path, name):
    (tmp_path / name).write_bytes(b"")
    with pytest.raises(DataFormatError, match="empty|no points"):
        read_point_file(tmp_path / name)


def test_a_bin_of_odd_size_is_an_error(tmp_path):
    np.zeros(7, "<f4").tofile(tmp_path / "a.bin")  # 28 bytes: neither 12 nor 16 per point
    with pytest.raises(DataFormatError, match="neither N x 12"):
        read_kitti_bin(tmp_path / "a.bin")
    (tmp_path / "b.bin").write_bytes(b"\0" * 30)
    with pytest.raises(DataFormatError, match="float32"):
        read_kitti_bin(tmp_path / "b.bin")


def _ply(path, pts: np.ndarray, inten: np.ndarray, name: str, *, cut: int = 0) -> None:
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
        f"property float x\nproperty float y\nproperty float z\nproperty float {name}\nend_header\n"
    )
    body = np.column_stack([pts, inten]).astype("<f4").tobytes()
    path.write_bytes(header.encode() + body[: len(body) - cut])


@pytest.mark.parametrize("name", ["intensity", "scalar_intensity", "scalar_Intensity"])
def test_ply_intensity_under_exporter_names(tmp_path, name):
    pts = spinning_scan("vlp16", order="firing")[:1000]
    inten = np.linspace(0, 1, 1000, dtype=np.float32)
    _ply(tmp_path / "a.ply", pts, inten, name)
    scan = read_point_file(tmp_path / "a.ply")
    np.testing.assert_array_equal(scan.intensity, inten)
    np.testing.assert_array_equal(scan.points, pts)


def test_a_truncated_ply_is_an_error_not_a_shorter_scan(tmp_path):
    # Open3D warns and returns zero-filled rows for the missing half, which would then be
    # dropped as non-returns: a silently shorter scan.
    pts = spinning_scan("vlp16", order="firing")[:1000]
    _ply(tmp_path / "a.ply", pts, np.zeros(1000, np.float32), "intensity", cut=8000)
    with pytest.raises(DataFormatError, match="truncated"):
        read_point_file(tmp_path / "a.ply")


def test_a_truncated_pcd_is_an_error(tmp_path):
    pts = spinning_scan("vlp16", order="firing")[:1000]
    header = (
        "# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\nDATA binary\n"
    )
    (tmp_path / "a.pcd").write_bytes(header.encode() + pts.astype("<f4").tobytes()[:6000])
    with pytest.raises(DataFormatError, match="truncated"):
        read_point_file(tmp_path / "a.pcd")
    (tmp_path / "b.pcd").write_bytes(header.encode() + pts.astype("<f4").tobytes())
    assert len(read_point_file(tmp_path / "b.pcd").points) == 1000


def test_xyz_files_with_header_commas_and_an_intensity_column(tmp_path):
    pts = np.round(spinning_scan("vlp16", order="firing")[:500], 3)
    (tmp_path / "a.xyz").write_text("".join(f"{x} {y} {z}\n" for x, y, z in pts))
    np.testing.assert_allclose(read_xyz(tmp_path / "a.xyz").points, pts, atol=1e-6)
    (tmp_path / "b.xyz").write_text("x,y,z,intensity\n" + "".join(f"{x},{y},{z},{i}\n" for i, (x, y, z) in
                                                                 enumerate(pts)))
    scan = read_point_file(tmp_path / "b.xyz")
    assert len(scan.points) == 500 and scan.intensity is not None and scan.intensity[-1] == 499


def test_an_xyz_line_with_another_width_is_named(tmp_path):
    (tmp_path / "a.xyz").write_text("1 2 3\n4 5 6\n7 8\n9 10 11\n")
    with pytest.raises(DataFormatError, match="line 3 has 2 values"):
        read_xyz(tmp_path / "a.xyz")
    (tmp_path / "b.xyz").write_text("1 2 3\n4 5 six\n")
    with pytest.raises(DataFormatError, match="not numbers"):
        read_xyz(tmp_path / "b.xyz")


def test_sensor_files_lwbench_and_ouster_both_layouts(tmp_path):
    s = get_sensor("hdl64e")
    (tmp_path / "sensor.json").write_text(json.dumps(s.to_dict(full=True)))
    assert read_sensor_file(tmp_path / "sensor.json") == s
    altitudes = list(np.linspace(21, -21, 64))
    legacy = {"beam_altitude_angles": altitudes, "data_format": {"columns_per_frame": 2048},
              "lidar_mode": "2048x10", "prod_line": "OS-1-64"}
    nested = {"beam_intrinsics": {"beam_altitude_angles": altitudes},
              "lidar_data_format": {"columns_per_frame": 512}, "config_params": {"lidar_mode": "512x20"},
              "sensor_info": {"prod_line": "OS-0-64"}}
    for meta, cols, rate in ((legacy, 2048, 10.0), (nested, 512, 20.0)):
        (tmp_path / "m.json").write_text(json.dumps(meta))
        m = read_sensor_file(tmp_path / "m.json")
        assert (m.n_beams, m.n_azimuth, m.rate_hz) == (64, cols, rate)
    (tmp_path / "bad.json").write_text(json.dumps({"beams": 64}))
    with pytest.raises(DataFormatError, match="neither an lwbench sensor.json"):
        read_sensor_file(tmp_path / "bad.json")
