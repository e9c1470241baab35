"""ROS bags in and out (lwbench.bags), on bags the tests write with rosbags: MCAP, SQLite, ROS 1."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from lwbench_plugins.files import KittiDataset
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from lwbench import DataFormatError, Frame, ParameterError, get_sensor
from lwbench.bags import BagDataset, frames_to_clouds, write_bag
from lwbench.bags.cloud import cloud_arrays, cloud_layout
from lwbench.cli import app
from lwbench.io import write_kitti_sequence
from lwbench.registry import get_registry
from lwbench.results.store import ResultStore
from lwbench.run import resolve_dataset
from lwbench.streamfile import open_payloads
from lwbench.testing import check_dataset, room_scan
from lwbench.transcode import decoded_frames

VLP16 = get_sensor("vlp16")
runner = CliRunner()


def _pose(x: float, yaw: float = 0.0) -> np.ndarray:
    p = np.eye(4)
    p[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    p[:3, 3] = (x, 0.2 * x, 0.0)
    return p


def _frames(n: int = 3, ring: bool = True) -> list[Frame]:
    out = []
    for i in range(n):
        f = room_scan(VLP16, seed=5, index=i, with_ring=ring, dropout=0.05)
        out.append(Frame(f.points, VLP16, index=i, timestamp=i / VLP16.rate_hz, pose=_pose(0.2 * i, 0.05 * i),
                         intensity=f.intensity, ring=f.ring))
    return out


def _digests(root: Path) -> dict[str, str]:
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


@pytest.mark.heavy
@pytest.mark.parametrize("storage", ["mcap", "sqlite3", "ros1"])
def test_a_written_bag_reads_back_exactly(tmp_path, storage):
    frames = _frames()
    out = tmp_path / ("bag.bag" if storage == "ros1" else "bag")
    write_bag(out, frames_to_clouds(frames), sensor=VLP16, storage=storage)
    target = out if storage == "ros1" else next(out.glob("*.mcap" if storage == "mcap" else "*.db3"))
    for path in {out, target}:  # the rosbag2 folder and the bare storage file both read
        before = _digests(out)
        assert BagDataset.sniff(path)
        ds = BagDataset(path=str(path))
        assert len(ds) == 3 and ds.has_poses and ds.sensor == VLP16 and ds.topic == "/lwbench/points"
        assert ds.sensor_source == "/lwbench/sensor in the bag" and ds.world == "world"
        for f, g in zip(frames, ds, strict=True):
            assert np.array_equal(f.points, g.points)
            assert np.array_equal(f.intensity, g.intensity) and np.array_equal(f.ring, g.ring)
            np.testing.assert_allclose(g.pose, f.pose, atol=1e-12)
        assert ds.frame_origin(2)["stamp_ns"] == 1_000_000_000 + 500_000_000  # 1 s + 2 / 4 Hz
        ds.close()
        assert _digests(out) == before  # reading never writes (no journal, no WAL, no index files)
        check_dataset(BagDataset, {"path": str(path)})


def test_the_loader_is_found_by_path_and_a_results_store_is_never_taken_for_a_bag(tmp_path):
    write_bag(tmp_path / "bag", frames_to_clouds(_frames(2)), sensor=VLP16, storage="sqlite3")
    reg = get_registry()
    db3 = next((tmp_path / "bag").glob("*.db3"))
    assert resolve_dataset(reg, str(db3), {}, 0).name == "rosbag"
    assert resolve_dataset(reg, str(tmp_path / "bag"), {}, 0).name == "rosbag"
    store = tmp_path / "results.db3"
    with ResultStore(store):
        pass
    assert not BagDataset.sniff(store)
    res = runner.invoke(app, ["run", "--dataset", str(tmp_path / "bag"), "--codec", "raw", "--store", str(db3)])
    assert res.exit_code == 2 and "not an lwbench results store" in res.output


@pytest.mark.heavy
def test_a_bag_and_the_same_scans_in_kitti_layout_give_the_same_leaderboard(tmp_path):
    kitti = write_kitti_sequence(_frames(3, ring=False), tmp_path / "kitti")
    scans = list(KittiDataset(path=str(kitti)))  # exactly what the KITTI run reads
    write_bag(tmp_path / "bag", frames_to_clouds(scans), sensor=scans[0].sensor, storage="mcap")
    boards = []
    for dataset in (kitti, tmp_path / "bag"):
        store = tmp_path / f"{dataset.name}.sqlite"
        res = runner.invoke(app, ["run", "--dataset", str(dataset), "--codec", "raw", "--codec", "rangeimage",
                                  "--codec", "random", "--store", str(store)])
        assert res.exit_code == 0, res.output
        res = runner.invoke(app, ["leaderboard", "--store", str(store), "--format", "json"])
        boards.append(json.loads(res.stdout))
    timing = ("_ms", "_x", "peak_mb")  # runtimes, and runtimes as multiples of the reference
    for a, b in zip(*boards, strict=True):
        assert (a["codec"], a["params"], a["frames"]) == (b["codec"], b["params"], b["frames"])
        assert a.keys() == b.keys()
        for k, v in a.items():
            if k in ("dataset", "dataset_id") or any(t in k for t in timing):
                continue
            # The bag carries each pose as a quaternion (tf), KITTI as a 3x4 matrix: trajectory
            # metrics agree to ~1e-11; every frame metric and the occupancy map exactly.
            assert b[k] == (pytest.approx(v, rel=1e-9, abs=1e-12) if isinstance(v, float) else v), (a["codec"], k)
        assert a["ate_rmse"] is not None and a["occ_iou"] is not None  # the poses came through the bag
        assert a["range_rmsd"] == b["range_rmsd"] and a["occ_iou"] == b["occ_iou"]


def test_decoded_clouds_go_back_into_a_bag_on_the_same_topic_and_stamps(tmp_path):
    frames = _frames(3)
    clouds = frames_to_clouds(frames, topic="/velodyne_points", frame_id="velodyne", t0_ns=1_700_000_000_123_456_789)
    src = write_bag(tmp_path / "src", clouds, sensor=VLP16, storage="mcap")
    res = runner.invoke(app, ["encode", str(src), "--codec", "rangeimage", "--out", str(tmp_path / "enc"), "--stream"])
    assert res.exit_code == 0, res.output
    stream = open_payloads(tmp_path / "enc" / "rangeimage.lwbs")
    assert stream.entries[0].name == "velodyne_points_1700000000123456789"
    for storage in ("sqlite3", "mcap"):
        out = tmp_path / f"decoded_{storage}"
        res = runner.invoke(app, ["decode", str(stream.path), "--out", str(out), "--format", "bag",
                                  "--storage", storage])
        assert res.exit_code == 0, res.output
        back, original = BagDataset(path=str(out)), BagDataset(path=str(src))
        assert back.topic == "/velodyne_points" and len(back) == 3
        assert [back.frame_origin(i)["stamp_ns"] for i in range(3)] == [c.stamp_ns for c in clouds]
        assert [back.frame_origin(i)["frame_id"] for i in range(3)] == ["velodyne"] * 3
        _, decoded = decoded_frames(get_registry(), stream)
        for i, d in enumerate(decoded):
            assert np.array_equal(back[i].points, d.points)
            np.testing.assert_allclose(back[i].pose, original[i].pose, atol=1e-5)  # the payload's float32 pose
    res = runner.invoke(app, ["decode", str(stream.path), "--out", str(tmp_path / "decoded_mcap"), "--format", "bag"])
    assert res.exit_code == 2 and "exists" in res.output


def _write_odometry_bag(path: Path, frames: list[Frame], odom_hz: float = 20.0) -> np.ndarray:
    """Clouds at 4 Hz in frame ``velodyne``, odometry odom -> base_link at 20 Hz with its own
    clock phase, a static mount base_link -> velodyne; returns the true velodyne poses."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    mount = np.eye(4)
    mount[:3, 3] = (0.3, 0.0, 0.8)

    def header(ns: int, frame: str):
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id=frame)

    def base_pose(t: float) -> np.ndarray:  # a smooth drive: 1 m/s along x, slow yaw
        return _pose(t, 0.1 * t)

    truth = []
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        c_cloud = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        c_odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        c_static = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
        t0 = 10**9
        tr = T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=0.3, y=0.0, z=0.8),
                                              rotation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))
        static = T["tf2_msgs/msg/TFMessage"](transforms=[T["geometry_msgs/msg/TransformStamped"](
            header=header(t0, "base_link"), child_frame_id="velodyne", transform=tr)])
        w.write(c_static, t0, ts.serialize_cdr(static, "tf2_msgs/msg/TFMessage"))
        for k in range(int(odom_hz * len(frames) / VLP16.rate_hz) + 3):
            t = k / odom_hz - 0.013  # odometry's clock is not the LiDAR's
            ns = t0 + int(round(t * 1e9))
            p = base_pose(t)
            q = Rotation.from_matrix(p[:3, :3]).as_quat()
            pose = T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=p[0, 3], y=p[1, 3], z=p[2, 3]),
                                               orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                              w=q[3]))
            cov = np.zeros(36)
            twist = T["geometry_msgs/msg/Twist"](linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                                                 angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0))
            odom = T["nav_msgs/msg/Odometry"](
                header=header(ns, "odom"), child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov))
            w.write(c_odom, ns, ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
        for c in frames_to_clouds(frames, topic="/points", frame_id="velodyne", t0_ns=t0):
            t = (c.stamp_ns - t0) * 1e-9
            truth.append(base_pose(t) @ mount)
            pts = np.asarray(c.points, np.float32)
            fields, step, data = cloud_layout(pts, c.intensity, c.ring)
            pf = T["sensor_msgs/msg/PointField"]
            msg = T["sensor_msgs/msg/PointCloud2"](
                header=header(c.stamp_ns, "velodyne"), height=1, width=len(pts),
                fields=[pf(name=n, offset=o, datatype=d, count=1) for n, o, d in fields], is_bigendian=False,
                point_step=step, row_step=step * len(pts), data=np.frombuffer(data, np.uint8), is_dense=True)
            w.write(c_cloud, c.stamp_ns, ts.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2"))
    return np.stack(truth)


def test_poses_come_from_odometry_and_the_static_mount_interpolated_at_each_stamp(tmp_path):
    truth = _write_odometry_bag(tmp_path / "odom", _frames(4))
    ds = BagDataset(path=str(tmp_path / "odom"), sensor="vlp16")
    assert ds.pose_source == "/odom + /tf_static" and ds.world == "odom"
    # Odometry samples every 50 ms: interpolating a 1 m/s drive between them is exact in
    # translation to float rounding, and the slerp of a constant yaw rate is exact.
    np.testing.assert_allclose(ds.poses, truth, atol=1e-9)
    assert not BagDataset(path=str(tmp_path / "odom"), sensor="vlp16", pose_topic="none").has_poses
    with pytest.raises(ParameterError, match="pose_topic '/nope'.*have: /odom"):
        BagDataset(path=str(tmp_path / "odom"), pose_topic="/nope")


def test_a_bag_with_two_cloud_topics_names_them(tmp_path):
    frames = _frames(2)
    clouds = frames_to_clouds(frames, topic="/front") + frames_to_clouds(frames, topic="/rear", t0_ns=2 * 10**9)
    write_bag(tmp_path / "two", clouds, sensor=VLP16)
    with pytest.raises(ParameterError, match="2 PointCloud2 topics \\(/front, /rear\\).*topic="):
        BagDataset(path=str(tmp_path / "two"))
    rear = BagDataset(path=str(tmp_path / "two"), topic="/rear")
    assert len(rear) == 2 and rear.frame_origin(0)["stamp_ns"] == 2 * 10**9
    with pytest.raises(ParameterError, match="no PointCloud2 topic '/side'"):
        BagDataset(path=str(tmp_path / "two"), topic="/side")


def test_a_damaged_bag_is_one_clear_error(tmp_path):
    write_bag(tmp_path / "bag", frames_to_clouds(_frames(2)), sensor=VLP16, storage="mcap")
    mcap = next((tmp_path / "bag").glob("*.mcap"))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap.read_bytes()[:2000])
    with pytest.raises(DataFormatError, match="cut.mcap"):
        BagDataset(path=str(cut))
    res = runner.invoke(app, ["inspect", str(cut)])
    assert res.exit_code == 2 and "cut.mcap" in res.output


def test_inspect_shows_a_bag(tmp_path):
    write_bag(tmp_path / "bag", frames_to_clouds(_frames(2)), sensor=VLP16, storage="sqlite3")
    res = runner.invoke(app, ["inspect", str(next((tmp_path / "bag").glob("*.db3")))])
    assert res.exit_code == 0, res.output
    assert "rosbag loader" in res.stdout and "/lwbench/points" in res.stdout and "/tf" in res.stdout


def _msg(fields, step, data, width, height=1, row_step=None, bigendian=False):
    f = [SimpleNamespace(name=n, offset=o, datatype=d, count=1) for n, o, d in fields]
    return SimpleNamespace(fields=f, point_step=step, row_step=row_step or step * width, width=width, height=height,
                           data=np.frombuffer(data, np.uint8), is_bigendian=bigendian)


def test_cloud_fields_are_found_by_name_in_a_padded_organized_ouster_layout():
    # Ouster's driver: x y z (pad) intensity t reflectivity ring ambient range, 48-byte points,
    # organized 2 x 3 with padded rows and a NaN non-return.
    rec = np.zeros((2, 4), dtype=np.dtype({
        "names": ["x", "y", "z", "intensity", "t", "reflectivity", "ring", "range"],
        "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u4"],
        "offsets": [0, 4, 8, 16, 20, 24, 26, 32], "itemsize": 48}))
    rec["x"] = [[1, 2, 3, np.nan], [4, np.nan, 6, 0]]
    rec["y"], rec["z"], rec["intensity"] = 1.0, 2.0, 7.0
    rec["t"] = [[10, 20, 30, 0], [40, 50, 60, 0]]
    rec["ring"] = [[0, 0, 0, 0], [1, 1, 1, 1]]
    fields = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("intensity", 16, 7), ("t", 20, 6), ("reflectivity", 24, 4),
              ("ring", 26, 4), ("range", 32, 6)]
    scan = cloud_arrays(_msg(fields, 48, rec.tobytes(), width=3, height=2, row_step=4 * 48))
    assert scan.points[:, 0].tolist() == [1, 2, 3, 4, 6]
    assert scan.ring.tolist() == [0, 0, 0, 1, 1] and scan.time.tolist() == [10, 20, 30, 40, 60]
    assert scan.intensity.tolist() == [7.0] * 5
    with pytest.raises(DataFormatError, match="no z field"):
        cloud_arrays(_msg([("x", 0, 7), ("y", 4, 7)], 8, bytes(16), width=2))
    with pytest.raises(DataFormatError, match="does not fit a 8-byte point"):
        cloud_arrays(_msg([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], 8, bytes(16), width=2))
    big = np.array([[1.5, 2.5, 3.5]], dtype=">f4")
    scan = cloud_arrays(_msg([("x", 0, 7), ("y", 4, 7), ("z", 8, 7)], 12, big.tobytes(), width=1, bigendian=True))
    assert scan.points.tolist() == [[1.5, 2.5, 3.5]]


@pytest.mark.heavy
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_a_mangled_bag_raises_only_lwbench_errors(tmp_path, storage):
    """Seeded flips and cuts in the storage file: refused with an lwbench error, or read -- never
    another exception (reading stays read-only either way)."""
    from lwbench import LwbenchError

    write_bag(tmp_path / "bag", frames_to_clouds(_frames(2)), sensor=VLP16, storage=storage)
    src = next((tmp_path / "bag").glob("*.mcap" if storage == "mcap" else "*.db3"))
    data = src.read_bytes()
    rng = np.random.default_rng(16)
    for case in range(40):
        blob = bytearray(data)
        if case % 2:
            blob = blob[: int(rng.integers(0, len(blob)))]
        else:
            for pos in rng.integers(0, len(blob), int(rng.integers(1, 6))):
                blob[pos] ^= 1 << int(rng.integers(0, 8))
        path = tmp_path / f"m{case}{src.suffix}"
        path.write_bytes(bytes(blob))
        try:
            ds = BagDataset(path=str(path), sensor="vlp16")
            for f in ds:
                assert f.points.dtype == np.float32
        except LwbenchError:
            pass
        finally:
            path.unlink()
