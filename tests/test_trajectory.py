"""Trajectory math against evo (GPL-3.0, imported here only as a test oracle) and known answers."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from _real import real_data_dir
from lwbench_metrics.trajectory import (
    Sim3,
    absolute_errors,
    ape,
    error_statistics,
    relative_errors,
    rpe,
    se3_inverse,
    umeyama,
)
from scipy.spatial.transform import Rotation

evo_metrics = pytest.importorskip("evo.core.metrics")
evo_trajectory = pytest.importorskip("evo.core.trajectory")

KITTI_POSES = real_data_dir() / "kitti00_frames0-1" / "poses.txt"
RELATIONS = (
    "translation_part",
    "rotation_angle_rad",
    "rotation_angle_deg",
    "rotation_part",
    "full_transformation",
)
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _se3(rotvec, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def random_trajectory(n: int, seed: int) -> np.ndarray:
    """A wandering 6-DoF path: chained random steps of ~1 m and a few degrees."""
    rng = np.random.default_rng(seed)
    poses = [_se3(rng.normal(0, 0.3, 3), rng.normal(0, 5, 3))]
    for _ in range(n - 1):
        poses.append(poses[-1] @ _se3(rng.normal(0, 0.05, 3), rng.normal([1, 0, 0], 0.2)))
    return np.stack(poses)


def perturbed(poses: np.ndarray, seed: int, t_sigma=0.05, r_sigma=0.01) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([p @ _se3(rng.normal(0, r_sigma, 3), rng.normal(0, t_sigma, 3)) for p in poses])


def kitti_poses() -> np.ndarray:
    rows = np.loadtxt(KITTI_POSES).reshape(-1, 3, 4)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows
    return poses


def _evo_stats(metric, ref: np.ndarray, est: np.ndarray) -> dict[str, float]:
    pair = (evo_trajectory.PosePath3D(poses_se3=list(ref)), evo_trajectory.PosePath3D(poses_se3=list(est)))
    metric.process_data(pair)
    return metric.get_all_statistics()


def _pairs():
    ref = random_trajectory(60, seed=1)
    yield "synthetic", ref, perturbed(ref, seed=2)
    ref = random_trajectory(25, seed=3)
    yield "synthetic-large-error", ref, perturbed(ref, seed=4, t_sigma=2.0, r_sigma=0.8)
    if KITTI_POSES.exists():  # the real KITTI ground truth, where the samples are
        k = kitti_poses()
        yield "kitti00", k, perturbed(k, seed=5)
        yield "kitti00-reversed", k, k[::-1].copy()


@pytest.mark.parametrize("relation", RELATIONS)
def test_ape_matches_evo(relation):
    for label, ref, est in _pairs():
        ours = ape(ref, est, relation)
        theirs = _evo_stats(evo_metrics.APE(evo_metrics.PoseRelation[relation]), ref, est)
        for s in STATS:
            assert ours[s] == pytest.approx(theirs[s], abs=1e-9, rel=0), (label, relation, s)


@pytest.mark.parametrize("relation", RELATIONS)
@pytest.mark.parametrize("delta", [1, 3])
def test_rpe_matches_evo(relation, delta):
    for label, ref, est in _pairs():
        if len(ref) <= delta:
            continue
        ours = rpe(ref, est, relation, delta=delta)
        theirs = _evo_stats(
            evo_metrics.RPE(evo_metrics.PoseRelation[relation], delta, evo_metrics.Unit.frames), ref, est
        )
        for s in STATS:
            assert ours[s] == pytest.approx(theirs[s], abs=1e-9, rel=0), (label, relation, delta, s)


@pytest.mark.parametrize("with_scale", [False, True])
def test_aligned_ape_matches_evo(with_scale):
    ref = random_trajectory(40, seed=7)
    moved = Sim3(Rotation.from_rotvec([0.2, -0.4, 1.0]).as_matrix(), np.array([10.0, -3.0, 2.0]), 1.7)
    est = moved.apply_poses(perturbed(ref, seed=8))
    evo_est = evo_trajectory.PosePath3D(poses_se3=list(est))
    evo_est.align(evo_trajectory.PosePath3D(poses_se3=list(ref)), correct_scale=with_scale)
    sim = umeyama(est[:, :3, 3], ref[:, :3, 3], with_scale=with_scale)
    ours = sim.apply_poses(est)
    np.testing.assert_allclose(ours, np.stack(evo_est.poses_se3), atol=1e-9)
    for relation in RELATIONS:
        theirs = _evo_stats(
            evo_metrics.APE(evo_metrics.PoseRelation[relation]), ref, np.stack(evo_est.poses_se3)
        )
        assert ape(ref, ours, relation)["rmse"] == pytest.approx(theirs["rmse"], abs=1e-9, rel=0)


def test_known_body_perturbation_gives_known_ape():
    ref = random_trajectory(30, seed=11)
    angle = np.radians(2.0)
    offset = _se3([0, 0, angle], [0.3, -0.4, 0.0])  # 0.5 m in the body frame, 2 deg about z
    est = ref @ offset
    np.testing.assert_allclose(absolute_errors(ref, est, "translation_part"), 0.5, atol=1e-12)
    np.testing.assert_allclose(absolute_errors(ref, est, "rotation_angle_deg"), 2.0, atol=1e-9)
    # The full-transformation error is |E - I|_F with E = offset^-1 for every pose.
    expected = np.linalg.norm(se3_inverse(offset) - np.eye(4))
    np.testing.assert_allclose(absolute_errors(ref, est, "full_transformation"), expected, atol=1e-12)


def test_known_world_shift_gives_known_ape_and_zero_rpe():
    ref = random_trajectory(30, seed=12)
    shift = np.eye(4)
    shift[:3, 3] = [1.0, 2.0, 2.0]
    stats = ape(ref, shift @ ref)
    assert stats["rmse"] == pytest.approx(3.0, abs=1e-12)
    assert stats["std"] == pytest.approx(0.0, abs=1e-12)
    assert rpe(ref, shift @ ref)["max"] == pytest.approx(0.0, abs=1e-12)


def test_one_bad_frame_shows_in_rpe_twice():
    ref = random_trajectory(10, seed=13)
    est = ref.copy()
    est[5] = est[5] @ _se3([0, 0, 0], [0, 0, 1.0])
    errs = relative_errors(ref, est, "translation_part")
    assert np.flatnonzero(errs > 1e-9).tolist() == [4, 5]
    np.testing.assert_allclose(errs[[4, 5]], 1.0, atol=1e-9)


@pytest.mark.parametrize("scale", [1.0, 0.37, 4.2])
def test_umeyama_recovers_known_sim3(scale):
    rng = np.random.default_rng(21)
    x = rng.normal(0, 10, (50, 3))
    truth = Sim3(Rotation.from_rotvec([0.5, -1.2, 2.5]).as_matrix(), np.array([3.0, -7.0, 0.5]), scale)
    y = truth.apply_points(x)
    est = umeyama(x, y, with_scale=True)
    np.testing.assert_allclose(est.rotation, truth.rotation, atol=1e-9)
    np.testing.assert_allclose(est.translation, truth.translation, atol=1e-8)
    assert est.scale == pytest.approx(scale, abs=1e-9)
    if scale == 1.0:
        rigid = umeyama(x, y, with_scale=False)
        np.testing.assert_allclose(rigid.apply_points(x), y, atol=1e-8)
    else:  # without scale the fit cannot be exact
        assert np.abs(umeyama(x, y).apply_points(x) - y).max() > 0.1


def test_umeyama_rejects_degenerate_points():
    with pytest.raises(ValueError, match="degenerate"):
        umeyama(np.ones((5, 3)), np.ones((5, 3)))


def test_se3_inverse_and_empty_statistics():
    T = random_trajectory(5, seed=9)
    np.testing.assert_allclose(se3_inverse(T) @ T, np.tile(np.eye(4), (5, 1, 1)), atol=1e-12)
    assert error_statistics(np.array([])) == dict.fromkeys(STATS)
    with pytest.raises(ValueError):
        ape(T, T[:3])


def test_evo_oracle_is_not_lenient():
    """Guard against a vacuous comparison: a wrong estimate does differ from evo's reference."""
    ref = random_trajectory(20, seed=30)
    est = perturbed(ref, seed=31)
    theirs = _evo_stats(evo_metrics.APE(evo_metrics.PoseRelation.translation_part), ref, copy.deepcopy(est))
    assert ape(ref, perturbed(ref, seed=32))["rmse"] != pytest.approx(theirs["rmse"], abs=1e-9, rel=0)
