"""The simulator: determinism, sensor geometry, noise model, poses, cache and registration."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from lwbench_plugins.sim import SimDataset
from lwbench_plugins.sim.mesh import Material, MeshBuilder
from lwbench_plugins.sim.raycast import Raycaster

from lwbench import ParameterError, SensorModel, get_sensor, import_open3d


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """Every test gets its own cache folder, so none reads scans another one wrote."""
    monkeypatch.setenv("LWBENCH_CACHE", str(tmp_path / "cache"))


def _same(a, b) -> bool:
    return all(
        np.array_equal(getattr(a, k), getattr(b, k)) and getattr(a, k).dtype == getattr(b, k).dtype
        for k in ("points", "intensity", "ring", "time", "pose")
    ) and a.timestamp == b.timestamp


def test_same_seed_gives_byte_identical_scans():
    a = SimDataset(frames=6, cache=False)
    b = SimDataset(frames=6, cache=False)
    # Read in different orders: a frame must not depend on which frames came before it.
    fa = [a[i] for i in (0, 5, 3)]
    fb = [b[i] for i in (3, 0, 5)]
    for x, y in zip(fa, (fb[1], fb[2], fb[0]), strict=True):
        assert x.points.tobytes() == y.points.tobytes()
        assert x.intensity.tobytes() == y.intensity.tobytes()
        assert _same(x, y)
    other = SimDataset(frames=1, seed=1, cache=False)[0]
    assert len(other) != len(fa[0]) or not np.array_equal(other.points, fa[0].points)


def test_tunnel_vlp16_scan_is_within_the_sensor_limits():
    ds = SimDataset(frames=0, cache=False)
    sensor = replace(get_sensor("vlp16"), range_noise_m=0.01)  # it declares the noise it adds
    assert ds.sensor == sensor and ds.has_poses
    for i in (0, len(ds) // 3, len(ds) - 1):
        f = ds[i]
        assert 10_000 <= len(f) <= 57_600
        r = np.linalg.norm(f.points, axis=1)
        assert r.min() >= sensor.min_range and r.max() <= sensor.max_range
        assert f.ring.min() >= 0 and f.ring.max() < sensor.n_beams
        assert np.all((f.intensity >= 0) & (f.intensity <= 1)) and f.intensity.max() > 0.05
        assert f.time.min() >= 0 and f.time.max() < 1 / sensor.rate_hz
        assert np.all(np.diff(f.time) >= 0)  # firing order


@pytest.mark.parametrize(
    "scene, sensor, low",
    [("urban", "hdl64e", 90_000), ("indoor", "vlp16", 30_000)],
)
def test_every_scene_scans_within_the_sensor_limits(scene, sensor, low):
    ds = SimDataset(scene=scene, frames=0, cache=False)
    assert ds.sensor.name == sensor
    for i in (0, len(ds) // 2, len(ds) - 1):
        f = ds[i]
        r = np.linalg.norm(f.points, axis=1)
        assert low <= len(f) <= ds.sensor.n_rays
        assert r.min() >= ds.sensor.min_range and r.max() <= ds.sensor.max_range
    again = SimDataset(scene=scene, frames=0, cache=False)[len(ds) - 1]
    assert np.array_equal(again.points, f.points)


def test_tunnel_starts_inside_by_default_and_outside_the_portal_from_zero():
    inside = SimDataset(frames=1, cache=False)
    outside = SimDataset(frames=1, start=0.0, cache=False)
    assert np.linalg.norm(inside.poses[0][:3, 3] - outside.poses[0][:3, 3]) > 12.0  # 16 m of path
    # Open ground in front of a rock face returns far fewer points than the inside of a drift.
    assert len(outside[0]) < 0.8 * len(inside[0])


def test_points_lie_on_their_beams_rays():
    ds = SimDataset(frames=2, noise=0.0, dropout=0.0, cache=False)
    sensor = ds.sensor
    f = ds[1]
    rows, cols, r = sensor.cells(f.points)
    assert np.array_equal(rows, f.ring.astype(np.int64))
    # Elevation of every point equals its ring's beam elevation (float32 rounding only).
    elev = np.arcsin(f.points[:, 2] / r)
    assert np.abs(elev - sensor.elevations_rad[f.ring]).max() < 1e-5
    # Its azimuth is its column's centre, and the column is the one its time says.
    col_from_time = np.round(f.time * sensor.rate_hz * sensor.n_azimuth).astype(np.int64)
    assert np.array_equal(cols, col_from_time)
    az = np.arctan2(f.points[:, 1], f.points[:, 0])
    assert np.abs(az - sensor.azimuths_rad()[cols]).max() < 1e-5


@pytest.mark.parametrize("sigma", [0.0, 0.01, 0.05])
def test_range_noise_on_a_plane_matches_sigma(sigma):
    b = MeshBuilder()
    b.boxes(np.array([[5.1, 0.0, 0.0]]), np.array([0.2, 40.0, 40.0]), 0.0, Material(0.5))  # face x = 5
    caster = Raycaster(b.build())
    sensor = get_sensor("vlp16")
    scan = caster.scan(sensor, np.eye(4), np.random.default_rng(0), noise=sigma, dropout=0.0)
    p = scan.points.astype(np.float64)
    r = np.linalg.norm(p, axis=1)
    true_r = 5.0 / (p[:, 0] / r)  # the plane x = 5 along each point's ray
    err = r - true_r
    assert len(p) > 5000
    assert abs(err.mean()) < max(3 * sigma / np.sqrt(len(p)), 1e-5)
    assert err.std() == pytest.approx(sigma, rel=0.05, abs=2e-6)
    # Intensity = reflectivity x cos(incidence)^(1/4): brightest straight ahead.
    cos = p[:, 0] / r
    assert np.allclose(scan.intensity, 0.5 * cos**0.25, atol=2e-3)


def test_dropout_removes_the_requested_share():
    full = SimDataset(frames=1, dropout=0.0, cache=False)[0]
    half = SimDataset(frames=1, dropout=0.5, cache=False)[0]
    assert len(half) / len(full) == pytest.approx(0.5, abs=0.02)


def test_poses_are_continuous_at_the_vehicle_speed():
    ds = SimDataset(frames=40, cache=False)
    poses = np.stack([ds[i].pose for i in range(len(ds))])
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert steps == pytest.approx(np.full(len(steps), 1.0 / 4.0), abs=0.005)  # 1 m/s at 4 Hz
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    angle = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert angle.max() < 3.0
    for p in poses:
        assert np.allclose(p[:3, :3] @ p[:3, :3].T, np.eye(3), atol=1e-9)
    ts = [ds[i].timestamp for i in range(3)]
    assert ts == pytest.approx([0.0, 0.25, 0.5])


def test_cached_frame_equals_the_simulated_one(tmp_path):
    ds = SimDataset(frames=3)
    first = ds[2]  # simulated, then written
    assert ds._cache is not None and (ds._cache.root / "velodyne" / "000002.bin").exists()
    again = SimDataset(frames=3)[2]  # read back from disk
    assert _same(first, again)
    fresh = ds.simulate(2)
    assert np.array_equal(fresh.points, again.points) and np.array_equal(fresh.ring, again.ring)
    # The folder is a KITTI sequence that lwbench's own loader reads back.
    from lwbench_plugins.files import KittiDataset

    for i in (0, 1):
        ds[i]
    kitti = KittiDataset(path=str(ds._cache.root))
    assert len(kitti) == 3 and kitti.sensor == ds.sensor
    k = kitti[2]
    assert np.array_equal(k.points, first.points) and np.allclose(k.pose, first.pose, atol=1e-6)


def test_corrupt_cache_entry_is_resimulated():
    ds = SimDataset(frames=1)
    ref = ds[0]
    (ds._cache.root / "velodyne" / "000000.bin").write_bytes(b"\x00" * 7)
    assert _same(SimDataset(frames=1)[0], ref)


def test_identity_ignores_the_cache_switch_but_not_the_data():
    assert SimDataset(frames=2).identity() == SimDataset(frames=2, cache=False).identity()
    assert SimDataset(frames=2).identity() != SimDataset(frames=2, noise=0.02).identity()


def test_motion_distortion_casts_each_column_from_its_own_pose():
    kw = dict(frames=2, dropout=0.0, noise=0.0, speed=4.0, cache=False)
    ds = SimDataset(distortion=True, **kw)
    f = ds[1]
    sensor = ds.sensor
    cols = np.round(f.time * sensor.rate_hz * sensor.n_azimuth).astype(np.int64)
    step = 4.0 / sensor.rate_hz
    s = ds.world.s_start + step * (1 + cols / sensor.n_azimuth)
    col_poses = ds.world.path.poses(s, ds.world.sensor_height)
    rel = np.einsum("ij,njk->nik", np.linalg.inv(f.pose), col_poses)  # column pose in the frame's
    ray = sensor.ray_directions()[f.ring, cols]
    expected_dir = np.einsum("nij,nj->ni", rel[:, :3, :3], ray)
    v = f.points - rel[:, :3, 3]
    r = np.linalg.norm(v, axis=1)
    # Every point lies on its ray cast from the pose at its column's firing time ...
    assert np.abs(v / r[:, None] - expected_dir).max() < 1e-4
    # ... which, at 4 m/s, is up to a metre ahead of the frame pose for the last columns.
    assert np.linalg.norm(rel[:, :3, 3], axis=1).max() == pytest.approx(step, abs=0.01)
    plain = SimDataset(**kw)[1]
    first_p, first_f = plain.points[plain.time == 0], f.points[f.time == 0]
    assert len(first_p) == len(first_f) and np.allclose(first_p, first_f, atol=1e-4)  # column 0: same pose


def test_parameters_are_checked():
    with pytest.raises(ParameterError, match="room for"):
        SimDataset(frames=100_000, cache=False)
    with pytest.raises(ParameterError):
        SimDataset(sensor="nope", cache=False)
    with pytest.raises(ParameterError):
        SimDataset(scene="moon", cache=False)
    with pytest.raises(ParameterError, match="past the end"):
        SimDataset(start=1e6, cache=False)


def test_preset_override_keeps_the_speed():
    ds = SimDataset(frames=2, sensor="os1-128", cache=False)
    f = ds[1]
    assert f.sensor.name == "os1-128" and len(f) <= 128 * 1024
    step = np.linalg.norm(ds[1].pose[:3, 3] - ds[0].pose[:3, 3])
    assert step == pytest.approx(0.1, abs=0.002)  # 1 m/s at 10 Hz


def test_sensor_file(tmp_path):
    custom = SensorModel("mini8", (-10.0, -7.0, -4.0, -1.0, 1.0, 4.0, 7.0, 10.0), 1.0, 0.2, 15.0, 5.0)
    path = tmp_path / "mini8.json"
    path.write_text(custom.to_json())
    f = SimDataset(frames=1, sensor=str(path), cache=False)[0]
    assert f.sensor == replace(custom, range_noise_m=0.01) and 0 < len(f) <= 8 * 360


def test_registered_as_a_dataset():
    from lwbench.registry import new_registry

    reg = new_registry()
    assert reg.dataset("sim") is SimDataset


def _icp(source, target, init: np.ndarray) -> np.ndarray:
    o3d = import_open3d()

    def cloud(f):
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(f.points.astype(np.float64)))
        pc = pc.voxel_down_sample(0.25)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.8, max_nn=30))
        return pc

    est = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    crit = o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=60)
    result = o3d.pipelines.registration.registration_icp(cloud(source), cloud(target), 1.0, init, est, crit)
    return result.transformation


@pytest.mark.parametrize("i", [20, 105])  # a straight, and mid-corner (4.3 deg yaw per frame)
def test_icp_between_consecutive_urban_scans_recovers_the_motion(i):
    ds = SimDataset(scene="urban", frames=0, cache=False)
    a, b = ds[i], ds[i + 1]
    truth = np.linalg.inv(a.pose) @ b.pose  # scan b in scan a's frame
    assert np.linalg.norm(truth[:3, 3]) == pytest.approx(1.0, abs=0.01)  # 10 m/s at 10 Hz
    est = _icp(b, a, np.eye(4))  # no prior: the whole metre must be found by ICP
    err = np.linalg.inv(truth) @ est
    assert np.linalg.norm(err[:3, 3]) < 0.05
    assert np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 0.5


def test_unusable_cache_folder_falls_back_to_simulating(tmp_path, monkeypatch):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("x")
    monkeypatch.setenv("LWBENCH_CACHE", str(blocker))
    with pytest.warns(UserWarning, match="scan cache"):
        ds = SimDataset(frames=1)
    assert ds._cache is None
    assert _same(ds[0], SimDataset(frames=1, cache=False)[0])
