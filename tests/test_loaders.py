"""Each loader on the real samples: point counts as the samples' README states them."""

from __future__ import annotations

import numpy as np
import pytest

from lwbench import import_open3d
from lwbench.datasets import KittiDataset, PointFileDataset
from lwbench.io import read_kitti_bin, read_pose_file, write_kitti_sequence

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
