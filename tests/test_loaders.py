"""Each loader on the real samples (point counts as the samples' README states them), and the
layouts on generated data: which files are scans, poses, sensors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _scans import spinning_scan, write_bin
from lwbench_plugins.files import KittiDataset, PointFileDataset

from lwbench import SensorModel, get_sensor, import_open3d, open_dataset
from lwbench.errors import DataFormatError, DataWarning, ParameterError
from lwbench.io import read_kitti_bin, read_point_file, read_pose_file, write_kitti_sequence

o3d = import_open3d()


def test_kitti00_xyz_only_bins_with_lidar_poses(real_data):
    ds = KittiDataset(path=str(real_data / "kitti00_frames0-1"))
    assert len(ds) == 2 and ds.has_poses
    assert [len(ds[0]), len(ds[1])] == [124_668, 124_605]
    assert ds[0].intensity is None  # 12 bytes per point: no intensity column
    # KITTI's poses are the camera's; the LiDAR pose Tr^-1 P Tr moves forward along +x.
    step = ds[1].pose[:3, 3] - ds[0].pose[:3, 3]
    assert step[0] == pytest.approx(0.86, abs=0.02) and abs(step[1]) < 0.1
    np.testing.assert_allclose(ds[0].pose, np.eye(4), atol=1e-6)


def test_kitti_object_xyzi_bin_keeps_intensity(real_data):
    ds = KittiDataset(path=str(real_data / "kitti_object_000008"))
    f = ds[0]
    assert len(f) == 17_238 and not ds.has_poses
    assert f.intensity is not None and 0 <= f.intensity.min() and f.intensity.max() <= 1.0


def test_ouster_kitti_layout_with_sensor_metadata(real_data):
    ds = KittiDataset(path=str(real_data / "ouster_os1-128_seq3"))
    assert [len(f) for f in ds] == [107_647, 107_357, 107_532]
    assert ds.sensor.n_beams == 128 and ds.has_poses
    assert np.linalg.norm(ds[2].pose[:3, 3]) == pytest.approx(0.498, abs=0.01)


def test_pcd_folder_binary_without_poses_drops_no_return_rows(real_data):
    ds = PointFileDataset(path=str(real_data / "hdl32_pair"))
    assert len(ds) == 2 and not ds.has_poses
    for frame, path, count in zip(ds, sorted((real_data / "hdl32_pair").glob("*.pcd")), (69_792, 69_088),
                                  strict=True):
        raw = o3d.t.io.read_point_cloud(str(path)).point.positions.numpy()
        zeros = int((raw == 0).all(axis=1).sum())
        assert len(raw) == count and zeros > 0
        assert len(frame) == count - zeros  # (0,0,0) rows are non-returns
        assert frame.intensity is not None


def test_pcd_binary_compressed_with_intensity_ring_time_and_stamped_poses(real_data):
    ds = PointFileDataset(path=str(real_data / "lidar64_static_pcd"))
    assert len(ds) == 3 and ds.has_poses
    f = ds[1]
    assert 80_000 < len(f) < 81_500
    assert f.intensity is not None and f.ring is not None and f.time is not None
    assert ds.sensor.n_beams == 61  # rings populated in this recording
    assert np.abs(ds[2].pose[:3, 3]).max() < 1e-3


def test_single_scan_file_is_a_one_frame_dataset(real_data):
    ds = PointFileDataset(path=str(real_data / "hdl32_pair" / "target.pcd"))
    assert len(ds) == 1


def test_kitti_writer_round_trip(tmp_path, vlp16_frame):
    pose = np.eye(4)
    pose[:3, 3] = [1, 2, 3]
    frames = [vlp16_frame, type(vlp16_frame)(vlp16_frame.points[:1000], vlp16_frame.sensor, 1, 0.25, pose)]
    frames[0] = type(vlp16_frame)(vlp16_frame.points, vlp16_frame.sensor, 0, 0.0, np.eye(4))
    write_kitti_sequence(frames, tmp_path / "seq")
    ds = KittiDataset(path=str(tmp_path / "seq"))
    assert len(ds) == 2 and ds.sensor == vlp16_frame.sensor
    np.testing.assert_array_equal(ds[0].points, frames[0].points)
    np.testing.assert_allclose(ds[1].pose, pose, atol=1e-6)


def test_ambiguous_bin_size_is_resolved_by_neighbour_distance(tmp_path, vlp16_frame):
    pts = vlp16_frame.points[:4800]  # 4800*12 bytes is divisible by 16 too
    pts.astype("<f4").tofile(tmp_path / "a.bin")
    np.testing.assert_array_equal(read_kitti_bin(tmp_path / "a.bin").points, pts)
    xyzi = np.column_stack([pts[:3600], np.full(3600, 0.5, np.float32)])
    xyzi.astype("<f4").tofile(tmp_path / "b.bin")
    back = read_kitti_bin(tmp_path / "b.bin")
    assert len(back.points) == 3600 and back.intensity is not None


def test_tum_pose_file(tmp_path):
    (tmp_path / "poses.txt").write_text("0.0 1 2 3 0 0 0 1\n0.1 1 2 4 0 0 0.7071068 0.7071068\n")
    keys, poses = read_pose_file(tmp_path / "poses.txt")
    assert keys == ["0.0", "0.1"]
    np.testing.assert_allclose(poses[1][:3, 3], [1, 2, 4])
    np.testing.assert_allclose(poses[1][:2, :2], [[0, -1], [1, 0]], atol=1e-6)


# ------------------------------------------------------------------ layouts (generated data)
def _kitti_seq(folder, n: int = 2, *, sensor: str = "vlp16", first: int = 0):
    (folder / "velodyne").mkdir(parents=True)
    for i in range(first, first + n):
        write_bin(folder / "velodyne" / f"{i:06d}.bin", spinning_scan(sensor, order="firing", seed=i))
    return folder


def _pose_rows(n: int) -> np.ndarray:
    rows = np.tile(np.eye(4)[:3].reshape(-1), (n, 1))
    rows[:, 3] = np.arange(n)  # frame i is at x = i
    return rows


def test_kitti_takes_scans_from_the_layout_and_names_the_skipped_files(tmp_path):
    seq = _kitti_seq(tmp_path / "seq")
    for i in range(2):  # per-point times beside the scans: 4 bytes per point
        np.zeros(1001, "<f4").tofile(seq / "velodyne" / f"times_{i:06d}.bin")
    np.zeros(10, "<f4").tofile(seq / "velodyne" / "notes.bin")
    with pytest.warns(DataWarning, match=r"1 file\(s\).*skipped: notes.bin$"):  # the times are read, not skipped
        ds = KittiDataset(path=str(seq))
    assert [p.name for p in ds.files] == ["000000.bin", "000001.bin"]
    assert ds.source_info()["skipped files"] == ["notes.bin"]
    assert "per-point times from" in ds.source_info()
    assert len(ds[1]) == len(spinning_scan("vlp16", order="firing", seed=1))


def test_a_flat_folder_of_bins_takes_one_naming_scheme(tmp_path):
    for i in range(3):
        write_bin(tmp_path / f"scan_{i}.bin", spinning_scan("vlp16", order="firing", seed=i))
    np.zeros(10, "<f4").tofile(tmp_path / "times_0.bin")
    ds = KittiDataset(path=str(tmp_path))
    assert [p.name for p in ds.files] == ["scan_0.bin", "scan_1.bin", "scan_2.bin"]
    with pytest.warns(DataWarning, match="times_0.bin has 40 bytes"):  # not scan_0's times after all: said on use
        assert ds[0].time is None
    np.zeros(10, "<f4").tofile(tmp_path / "times_1.bin")
    np.zeros(10, "<f4").tofile(tmp_path / "times_2.bin")  # 3 per-point time files are still no scans
    assert [p.name for p in KittiDataset(path=str(tmp_path)).files] == ["scan_0.bin", "scan_1.bin", "scan_2.bin"]
    for i in range(3):
        np.zeros(10, "<f4").tofile(tmp_path / f"other_{i}.bin")  # now two schemes of 3 scans each
    with pytest.raises(DataFormatError, match=r"named in several ways \((scan|other)_N.bin, (scan|other)_N.bin\)"):
        KittiDataset(path=str(tmp_path))


def test_scans_are_in_natural_order_so_poses_match(tmp_path):
    for i in (1, 2, 10):
        np.savetxt(tmp_path / f"scan_{i}.xyz", spinning_scan("vlp16", order="firing", seed=i)[:200])
    np.savetxt(tmp_path / "poses.txt", _pose_rows(3))
    ds = PointFileDataset(path=str(tmp_path))
    assert [p.name for p in ds.files] == ["scan_1.xyz", "scan_2.xyz", "scan_10.xyz"]
    assert ds.has_poses and PointFileDataset.sniff(tmp_path)


def test_numbered_scans_take_the_pose_and_time_rows_of_their_number(tmp_path):
    seq = _kitti_seq(tmp_path / "seq", first=5)
    np.savetxt(seq / "poses.txt", _pose_rows(10))
    np.savetxt(seq / "times.txt", np.arange(10) * 0.1)
    ds = KittiDataset(path=str(seq))
    assert ds[0].pose[0, 3] == 5 and ds[1].pose[0, 3] == 6
    assert ds[1].timestamp == pytest.approx(0.6)
    np.savetxt(seq / "poses.txt", _pose_rows(6))
    with pytest.raises(DataFormatError, match="6 rows, but scan 000006.bin is frame 6"):
        KittiDataset(path=str(seq))


def _official_tree(root):
    seq = _kitti_seq(root / "sequences" / "00", n=3)
    (root / "poses").mkdir()
    np.savetxt(root / "poses" / "00.txt", _pose_rows(3))
    (seq / "calib.txt").write_text("P0: " + " ".join(["0"] * 12) + "\nTr: " + " ".join(
        f"{v:.1f}" for v in np.eye(4)[:3].reshape(-1)) + "\n")
    np.savetxt(seq / "times.txt", np.arange(3) * 0.1)
    _kitti_seq(root / "sequences" / "11", n=1)  # a test sequence: no poses
    return root


def test_official_kitti_odometry_tree_loads_its_poses(tmp_path):
    root = _official_tree(tmp_path / "dataset")
    by_folder = KittiDataset(path=str(root / "sequences" / "00"))
    by_param = KittiDataset(path=str(root), sequence="00")
    for ds in (by_folder, by_param):
        assert len(ds) == 3 and ds.has_poses
        assert ds[2].pose[0, 3] == 2
        assert ds.source_info()["poses from"].startswith(str(root / "poses" / "00.txt"))
    assert not KittiDataset(path=str(root), sequence="11").has_poses
    assert KittiDataset.sniff(root)


def test_a_kitti_layout_that_does_not_load_says_which_do(tmp_path):
    root = _official_tree(tmp_path / "dataset")
    with pytest.raises(DataFormatError, match="sequence=NN"):
        KittiDataset(path=str(root))
    with pytest.raises(DataFormatError, match=r"no sequence '07'.*sequences: 00, 11.*layouts that load"):
        KittiDataset(path=str(root), sequence="07")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataFormatError, match="layouts that load: SEQ/velodyne/NNNNNN.bin"):
        KittiDataset(path=str(tmp_path / "empty"))


def test_scans_of_two_sensors_in_one_folder_are_refused(tmp_path):
    write_bin(tmp_path / "000000.bin", spinning_scan("vlp16", order="ring", ranges=(4.0, 9.0)))
    write_bin(tmp_path / "000001.bin", spinning_scan("hdl64e", order="ring", ranges=(4.0, 9.0)))
    ds = KittiDataset(path=str(tmp_path))
    assert len(ds[0]) > 0 and ds.sensor.n_beams == 16
    with pytest.raises(DataFormatError, match=r"000001.bin is not from the sensor of 000000.bin.*16 beams.*64 beams"):
        ds[1]
    # naming the sensor is the way out: then there is nothing to derive, nothing to compare
    assert len(KittiDataset(path=str(tmp_path), sensor="hdl64e")[1]) > 0


def test_sensor_param_takes_a_preset_a_sensor_json_or_ouster_metadata(tmp_path):
    seq = _kitti_seq(tmp_path / "seq")
    assert KittiDataset(path=str(seq), sensor="hdl64e").sensor == get_sensor("hdl64e")
    custom = SensorModel("mine", (-10.0, 0.0, 10.0), 0.5, 0.2, 30.0, 5.0)
    (tmp_path / "mine.json").write_text(json.dumps(custom.to_dict()))
    assert PointFileDataset(path=str(seq / "velodyne"), sensor=str(tmp_path / "mine.json")).sensor == custom
    (tmp_path / "meta.json").write_text(json.dumps({"beam_altitude_angles": list(np.linspace(16, -16, 32)),
                                                    "data_format": {"columns_per_frame": 2048}}))
    ds = KittiDataset(path=str(seq), sensor=str(tmp_path / "meta.json"))
    assert (ds.sensor.n_beams, ds.sensor.n_azimuth) == (32, 2048)
    assert ds.source_info()["sensor source"] == f"file {tmp_path / 'meta.json'}"
    with pytest.raises(ParameterError, match="neither a preset"):
        KittiDataset(path=str(seq), sensor="hdl-64")  # at once, not on every frame


def test_derived_sensor_records_how(tmp_path):
    seq = _kitti_seq(tmp_path / "seq")
    info = KittiDataset(path=str(seq)).source_info()
    assert info["sensor source"] == "derived from 000000.bin (firing-major order)"
    assert info["derived sensor"]["beams"] == 16 and info["derived sensor"]["columns"] == 3600


def test_a_folder_of_nuscenes_sweeps_loads_with_rings(tmp_path):
    from test_formats import NUSCENES_NAME, _nuscenes_points

    for i in range(2):
        _nuscenes_points().tofile(tmp_path / NUSCENES_NAME.replace("1533151603547590", f"153315160354759{i}"))
    assert PointFileDataset.sniff(tmp_path) and not KittiDataset.sniff(tmp_path)
    ds = PointFileDataset(path=str(tmp_path))
    f = ds[1]
    assert len(f) == 8000 and f.ring is not None and f.ring.max() == 31
    assert ds.sensor_choice.derivation.method == "ring field" and ds.sensor.n_beams == 32


def test_kitti00_derived_sensor_is_the_hdl64e(real_data):
    ds = KittiDataset(path=str(real_data / "kitti00_frames0-1"))
    assert ds.sensor.n_beams == 64 and 2000 <= ds.sensor.n_azimuth <= 2100
    assert ds.sensor_choice.derivation.method == "ring-major order"
    assert len(ds[1]) == 124_605  # frame 1 is checked against frame 0's model: same sensor


# ----------------------------------------------------------------- layouts read as they are (issue 25)
def test_a_folder_of_nuscenes_sweeps_from_two_time_zones_loads(tmp_path):
    from test_formats import _nuscenes_points

    # nuScenes names carry the log's UTC offset: Boston's -0400 and Singapore's +0800 side by side.
    for i, zone in enumerate(("-0400", "+0800", "-0400")):
        name = f"n008-2018-08-01-15-16-36{zone}__LIDAR_TOP__15331516035475{i}0.pcd.bin"
        _nuscenes_points().tofile(tmp_path / name)
    ds = PointFileDataset(path=str(tmp_path))
    assert len(ds) == 3 and len(ds[2]) == 8000 and ds[2].ring is not None


def test_raw_scans_beside_per_point_time_files_load_with_their_times(tmp_path):
    scans = [spinning_scan("vlp16", order="firing", seed=i) for i in range(2)]
    for i, pts in enumerate(scans):
        write_bin(tmp_path / f"raw_{i:02d}.bin", pts)
        np.linspace(0.0, 0.1, len(pts)).astype("<f8").tofile(tmp_path / f"times_{i:02d}.bin")
    import warnings

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        ds = KittiDataset(path=str(tmp_path))
    # The time files are read beside their scans: not "skipped" (issue 32's small item).
    assert not [w for w in said if "skipped" in str(w.message)], [str(w.message) for w in said]
    assert [p.name for p in ds.files] == ["raw_00.bin", "raw_01.bin"]
    f = ds[1]
    assert len(f) == len(scans[1]) and f.time is not None
    np.testing.assert_allclose(f.time, np.linspace(0.0, 0.1, len(scans[1])))
    assert "per-point times from" in ds.source_info()


def _vtk(path, pts: np.ndarray, intensity: np.ndarray, *, declared: int | None = None) -> None:
    """Legacy ASCII VTK polydata as libpointmatcher writes it (POINTS, VERTICES, POINT_DATA)."""
    n = len(pts)
    lines = ["# vtk DataFile Version 3.0", "File created by libpointmatcher", "ASCII", "DATASET POLYDATA",
             f"POINTS {declared or n} float", *(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts),
             f"VERTICES {n} {2 * n}", *(f"1 {i}" for i in range(n)), f"POINT_DATA {n}",
             "SCALARS intensity float", "LOOKUP_TABLE default", *(f"{v:.6f}" for v in intensity)]
    path.write_text("\n".join(lines) + "\n")


def test_vtk_polydata_scans_load_with_their_intensity(tmp_path):
    pytest.importorskip("vtkmodules")
    pts = spinning_scan("vlp16", order="firing")[:3000]
    inten = np.linspace(0, 1, len(pts)).astype(np.float32)
    for i in range(2):
        _vtk(tmp_path / f"cloud_{i}.vtk", pts, inten)
    ds = PointFileDataset(path=str(tmp_path))
    assert PointFileDataset.sniff(tmp_path) and len(ds) == 2
    np.testing.assert_allclose(ds[0].points, pts, atol=1e-5)
    np.testing.assert_allclose(ds[0].intensity, inten, atol=1e-5)
    _vtk(tmp_path / "cut.vtk", pts, inten, declared=len(pts) + 500)
    with pytest.raises(DataFormatError, match="declares 3500 points"):
        read_point_file(tmp_path / "cut.vtk")
    (tmp_path / "grid.vtk").write_text("# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\n")
    with pytest.raises(DataFormatError, match="POLYDATA"):
        read_point_file(tmp_path / "grid.vtk")


def test_a_later_scan_beyond_the_derived_range_window_is_said(tmp_path):
    near = spinning_scan("vlp16", order="firing", ranges=(4.0, 20.0))
    far = spinning_scan("vlp16", order="firing", ranges=(4.0, 35.0), seed=1)
    write_bin(tmp_path / "000000.bin", near)
    write_bin(tmp_path / "000001.bin", far)
    ds = KittiDataset(path=str(tmp_path))
    assert ds.sensor.max_range == 20.0
    with pytest.warns(DataWarning, match=r"000001.bin: \d+ returns beyond the max range 20 m.*max_range=M"):
        ds[1]
    wide = KittiDataset(path=str(tmp_path), max_range=40.0)
    assert wide.sensor.max_range == 40.0


def test_a_ring_field_with_placeholders_gives_the_real_table_and_step():
    from lwbench.testing import HDL32_NOMINAL, hdl32_ring_scan

    frame = hdl32_ring_scan(firings=1086)  # every firing written, misses as one placeholder point
    s = frame.sensor  # derived from the ring field, as the loaders do
    assert s.n_beams == 32
    np.testing.assert_allclose(s.elevations_deg, HDL32_NOMINAL, atol=0.16)  # lasers are up to 0.15 off
    assert s.azimuth_step_deg == pytest.approx(360 / 1086)  # firings from the points per ring
    assert s.min_range == 0.05  # above the placeholders (5e-5 m): no returns; not at the nearest return


@pytest.mark.heavy
def test_a_long_folder_opens_and_gives_its_poses_without_reading_its_scans(tmp_path, monkeypatch):
    """A 5,000-scan drive is opened by listing it: no scan is read until a frame is asked for,
    and the sequence metrics' poses come from the poses file (issue 31)."""
    import lwbench_plugins.files.loaders as loaders

    from lwbench import Frame

    sensor = get_sensor("vlp16")
    rng = np.random.default_rng(0)

    def frames():
        for i in range(5000):
            pose = np.eye(4)
            pose[0, 3] = 0.1 * i
            pts = rng.uniform(-5, 5, (16, 3)).astype(np.float32)
            yield Frame(pts, sensor, index=i, timestamp=i / 10, pose=pose)

    folder = write_kitti_sequence(frames(), tmp_path / "drive")
    reads = []
    for name in ("read_point_file", "read_kitti_bin"):
        real = getattr(loaders, name)
        monkeypatch.setattr(loaders, name, lambda *a, _real=real, **k: reads.append(a[0]) or _real(*a, **k))
    ds = open_dataset(folder)
    assert len(ds) == 5000 and ds.has_poses
    assert ds.pose(4321)[0, 3] == pytest.approx(432.1)
    assert reads == []
    assert len(ds[4321].points) == 16 and len(reads) == 1


# ----------------------------------------------------------------- no-return markers (issue 32)
def _nuscenes_marked(tmp_path, marker) -> list:
    # marker None: the synthetic scan's own marker, a hair from the origin (the clean case)
    """Two HDL-32E ring-layout sweeps written as nuScenes .pcd.bin (x, y, z, intensity, ring)."""
    from lwbench.synthetic import hdl32_ring_scan

    frames = []
    for i in range(2):
        f = hdl32_ring_scan(seed=i, marker=marker)
        rows = np.column_stack([f.points, f.intensity, f.ring.astype(np.float32)]).astype("<f4")
        rows.tofile(tmp_path / f"n015-2018-07-24-11-22-45+0800__LIDAR_TOP__15324029476{i}0000.pcd.bin")
        frames.append(f)
    return frames


@pytest.mark.heavy
def test_no_return_copies_far_from_the_origin_are_left_out_of_the_derived_sensor(tmp_path):
    """Older nuScenes files write each ray without a return as one point 0.19 m out: before, nine
    upper rings were derived at its -3.68 deg and the minimum range came out 0.1 m."""
    from typer.testing import CliRunner

    from lwbench.cli import app
    from lwbench.results.leaderboard import build_leaderboard
    from lwbench.results.store import ResultStore
    from lwbench.sensors.derive import derive_sensor
    from lwbench.synthetic import NUSCENES_NO_RETURN

    (tmp_path / "scans").mkdir()
    frames = _nuscenes_marked(tmp_path / "scans", NUSCENES_NO_RETURN)
    (tmp_path / "clean").mkdir()
    first_clean = _nuscenes_marked(tmp_path / "clean", None)[0]
    clean = derive_sensor(first_clean.points, ring=first_clean.ring, rate_hz=20.0)
    marked = PointFileDataset(path=str(tmp_path / "scans"))
    assert marked.sensor.n_beams == 32
    assert np.allclose(marked.sensor.elevations_deg, clean.sensor.elevations_deg, atol=1e-6)
    assert marked.sensor.azimuth_step_deg == pytest.approx(clean.sensor.azimuth_step_deg)
    assert 0.19 < marked.sensor.min_range <= 0.21  # just beyond the markers 0.19 m out: they are no returns
    assert len(marked[1]) == len(frames[1].points)  # the second sweep is the same sensor's
    store = tmp_path / "r.sqlite"
    res = CliRunner().invoke(app, ["run", "--dataset", str(tmp_path / "scans"), "--codec", "laz",
                                   "--no-sequence-metrics", "--store", str(store)])
    assert res.exit_code == 0, res.output
    with ResultStore(store, readonly=True) as results:
        (laz,) = build_leaderboard(results)
        assert laz.stats["coverage"]["mean"] == 1.0 and laz.frames == 2
