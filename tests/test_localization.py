"""Localization and odometry task metrics on a ray-cast street with known poses."""

from __future__ import annotations

import numpy as np
import pytest
from _task_scene import StreetDataset
from lwbench_metrics.localization import ICP_PARAMS, build_map, track_against_map
from lwbench_metrics.task import LocalizationMetric, OdometryMetric, lwbench_metrics
from scipy.spatial.transform import Rotation

from lwbench import SequenceEvaluation, SequenceMetric

DESIGN_IDS = {"ate_rmse", "ate_mean", "rot_err_deg", "rpe_trans", "rpe_rot_deg", "map_points", "map_share",
              "icp_failures"}  # fmt: skip


@pytest.fixture(scope="module")
def street() -> StreetDataset:
    return StreetDataset(n=10, seed=0)


def _seq(ds: StreetDataset, decoded: list[np.ndarray], name: str = "test") -> SequenceEvaluation:
    return SequenceEvaluation(ds, list(range(len(ds))), decoded, name, {})


def _originals(ds: StreetDataset) -> list[np.ndarray]:
    return [ds[i].points for i in range(len(ds))]


def test_registration_and_ids():
    classes = lwbench_metrics()
    assert LocalizationMetric in classes and OdometryMetric in classes
    assert all(issubclass(c, SequenceMetric) for c in classes)
    ids = [i for c in classes for i in c.ids]
    assert len(ids) == len(set(ids))
    assert DESIGN_IDS <= set(LocalizationMetric.ids)


@pytest.mark.heavy
def test_map_tracking_recovers_the_trajectory_from_original_scans(street):
    out = LocalizationMetric().compute(_seq(street, _originals(street)))
    assert set(out) == set(LocalizationMetric.ids)
    assert out["icp_failures"] == 0
    assert out["ate_rmse"] < 0.02  # 1 cm range noise; the path is 9 m long
    assert out["ate_mean"] <= out["ate_rmse"]
    assert out["rot_err_deg"] < 0.05
    assert out["rpe_trans"] < 0.02
    n_orig = sum(len(p) for p in _originals(street))
    assert out["map_share"] == pytest.approx(out["map_points"] / n_orig)
    assert 0 < out["map_share"] < 1


@pytest.mark.heavy
def test_tracking_starts_from_the_previous_estimate_and_follows_a_wrong_start(street):
    """A start 0.4 m off must be pulled back onto the map within one frame (the map is at GT)."""
    scans = _originals(street)
    world_map = build_map(scans, street.poses)
    start = street.poses[0].copy()
    start[:3, 3] += [0.4, -0.3, 0.0]
    result = track_against_map(scans, start, world_map, poses=street.poses)
    err = np.linalg.norm(result.poses[1:, :3, 3] - street.poses[1:, :3, 3], axis=1)
    assert err.max() < 0.05


@pytest.mark.heavy
def test_inconsistent_decoded_scans_localize_worse(street):
    """Scans each displaced by a different 0.3 m / 1 deg error make a blurred map and a worse track."""
    rng = np.random.default_rng(3)
    bad = []
    for p in _originals(street):
        R = Rotation.from_rotvec(rng.normal(0, np.radians(1.0), 3)).as_matrix().astype(np.float32)
        bad.append(p @ R.T + rng.normal(0, 0.3, 3).astype(np.float32))
    good = LocalizationMetric().compute(_seq(street, _originals(street)))
    worse = LocalizationMetric().compute(_seq(street, bad, "bad"))
    assert worse["ate_rmse"] > 5 * good["ate_rmse"]
    assert worse["ate_rmse"] > 0.05


@pytest.mark.heavy
def test_empty_decoded_scans_count_as_failures_not_nan(street):
    decoded = _originals(street)
    decoded[4] = np.zeros((0, 3), np.float32)
    out = LocalizationMetric().compute(_seq(street, decoded))
    assert out["icp_failures"] == 1
    assert all(v is not None and np.isfinite(v) for v in out.values())
    empty = [np.zeros((0, 3), np.float32) for _ in range(len(street))]
    out = LocalizationMetric().compute(_seq(street, empty))
    assert out["icp_failures"] == len(street) - 1 and out["map_points"] == 0
    assert out["ate_rmse"] > 1.0  # stuck at the first pose while the sensor drove 9 m


@pytest.mark.heavy
def test_odometry_follows_the_trajectory_and_drifts_more_than_map_tracking(street):
    seq = _seq(street, _originals(street))
    odo = OdometryMetric().compute(seq)
    loc = LocalizationMetric().compute(seq)
    assert set(odo) == set(OdometryMetric.ids)
    assert odo["odom_icp_failures"] == 0
    assert odo["odom_rpe_trans"] < 0.05  # per 1 m step
    assert odo["odom_ate_rmse"] < 0.3  # drift over 9 m
    assert odo["odom_ate_rmse"] > loc["ate_rmse"]


def test_single_frame_gives_none_not_nan(street):
    seq = SequenceEvaluation(street, [0], [street[0].points], "one", {})
    out = LocalizationMetric().compute(seq)
    assert out["ate_rmse"] is None and out["rpe_trans"] is None
    assert out["map_points"] > 0
    assert all(v is None for v in OdometryMetric().compute(seq).values())


def test_leave_one_out_does_not_let_a_distorted_scan_lock_onto_itself(street):
    """A scan decoded 0.1 m off must show as a 0.1 m error; with its own points in a sparse map
    (20 % of the points: many map voxels then hold one scan's points) most of the error hides."""
    rng = np.random.default_rng(0)
    scans = [p[rng.random(len(p)) < 0.2] for p in _originals(street)]
    scans[5] = scans[5] + np.float32([0.1, 0.0, 0.0])
    world_map = build_map(scans, street.poses)
    err = {}
    for loo in (True, False):
        result = track_against_map(scans, street.poses[0], world_map, dict(ICP_PARAMS, leave_one_out=loo),
                                   poses=street.poses)
        err[loo] = np.linalg.norm(result.poses[5, :3, 3] - street.poses[5, :3, 3])
    assert err[True] == pytest.approx(0.1, abs=0.02)
    assert err[False] < 0.05


def test_reach_columns_hold_everything_within_each_points_radius():
    from lwbench_metrics.voxel_map import in_columns, reach_columns

    rng = np.random.default_rng(0)
    centres = rng.uniform(-50, 50, (150, 3))
    radii = rng.uniform(0.5, 15, 150)
    radii[:10] = 8.0  # a radius that is a whole number of columns: the edge case of the dilation
    probes = rng.uniform(-80, 80, (40_000, 3))
    d = np.linalg.norm(probes[:, None, :2] - centres[None, :, :2], axis=2)
    needed = (d <= radii[None]).any(axis=1)
    kept = in_columns(probes, reach_columns(centres, radii))
    assert needed.sum() > 1000 and not np.any(needed & ~kept)
    assert kept.sum() < 1.6 * needed.sum()  # whole columns, not the whole map


@pytest.mark.heavy
def test_the_cropped_target_tracks_exactly_as_the_whole_ball(street, monkeypatch):
    """The crop only drops map voxels no correspondence can reach: poses equal the ball's; and a
    registration that moves points beyond half their room is redone on the ball."""
    import lwbench_metrics.localization as loc

    gt = np.stack([street.pose(i) for i in range(len(street))])
    scans = _originals(street)
    world_map = build_map(scans, gt, ICP_PARAMS)
    cropped = track_against_map(scans, gt[0], world_map, ICP_PARAMS, poses=gt)
    assert cropped.redone == 0
    original_cloud = loc.VoxelMap.cloud
    monkeypatch.setattr(loc.VoxelMap, "cloud", lambda self, without=None, around=None, columns=None:
                        original_cloud(self, without, around))
    ball = track_against_map(scans, gt[0], world_map, ICP_PARAMS, poses=gt)
    monkeypatch.setattr(loc.VoxelMap, "cloud", original_cloud)
    np.testing.assert_allclose(cropped.poses, ball.poses, atol=1e-9)
    monkeypatch.setattr(loc, "TRANSLATION_ROOM_M", 1e-4)
    monkeypatch.setattr(loc, "ROTATION_ROOM_DEG", 1e-4)
    tight = track_against_map(scans, gt[0], world_map, ICP_PARAMS, poses=gt)
    assert tight.redone > 0
    np.testing.assert_allclose(tight.poses, ball.poses, atol=1e-9)
    world_map.close()
