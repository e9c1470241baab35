"""KISS-ICP odometry metric: follows a ray-cast street, drifts on distorted scans, fails as a row."""

from __future__ import annotations

import numpy as np
import pytest
from _task_scene import StreetDataset, street_poses
from lwbench_metrics import kiss
from lwbench_metrics.kiss import KISS_SETTINGS, KissOdometryMetric, kiss_trajectory

from lwbench import Dataset, Frame, SequenceEvaluation
from lwbench.geometry import transform
from lwbench.registry import get_registry

pytest.importorskip("kiss_icp")


class RigidStreet(Dataset):
    """One ray-cast street scan seen from poses along the street: every frame samples the world
    exactly as the first did, so the motion between frames is the only thing to recover (a
    re-cast scan would move its ground rings with the sensor, which point-to-point ICP partly
    follows -- measured in docs/task_metrics.md)."""

    name = "rigid-street"

    def __init__(self, n: int = 8, step: float = 0.5) -> None:
        super().__init__()
        street = StreetDataset(n=1, seed=0)
        self.sensor = street.sensor
        self.poses = street_poses(n, step)
        world = transform(street[0].points, street.poses[0])
        self._points = [transform(world, np.linalg.inv(p)).astype(np.float32) for p in self.poses]

    def __len__(self) -> int:
        return len(self._points)

    def frame(self, index: int) -> Frame:
        return Frame(self._points[index], self.sensor, index=index, pose=self.poses[index])

    @property
    def has_poses(self) -> bool:
        return True

    def identity(self) -> str:
        return f"rigid-street:{id(self)}"


@pytest.fixture(scope="module")
def street() -> RigidStreet:
    return RigidStreet()


def _seq(ds: Dataset, decoded: list[np.ndarray]) -> SequenceEvaluation:
    return SequenceEvaluation(ds, list(range(len(ds))), decoded, "test", {})


def _originals(ds: Dataset) -> list[np.ndarray]:
    return [ds[i].points for i in range(len(ds))]


def test_registered_with_kiss_ids():
    reg = get_registry()
    assert "kiss" in reg.sequence_metrics
    assert all("kiss" in i for i in KissOdometryMetric.ids)
    assert KissOdometryMetric.settings["max_num_threads"] == 1 and not KissOdometryMetric.settings["deskew"]


def test_recovers_the_motion_of_the_original_scans(street):
    out = KissOdometryMetric().compute(_seq(street, _originals(street)))
    assert set(out) == set(KissOdometryMetric.ids)
    assert out["kiss_failed"] == 0
    # Measured 8 mm / 13 mm over 3.5 m (7 registrations): the street constrains its own axis
    # only through poles and parked cars; the error would be metres if the chaining were wrong.
    assert out["kiss_ate_rmse"] < 0.02
    assert out["kiss_rpe_trans"] < 0.03
    assert all(v is not None and np.isfinite(v) for v in out.values())


def test_deterministic_and_chained_from_the_first_pose(street):
    a = kiss_trajectory(_originals(street), street.poses[0], 60.0)
    b = kiss_trajectory(_originals(street), street.poses[0], 60.0)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a[0], street.poses[0])


def test_inconsistent_scans_drift_more(street):
    """Each decoded scan shifted by its own 5-10 cm offset (a codec whose error moves with the
    scan): KISS-ICP follows the shifts, so its per-frame error grows well above the originals'."""
    rng = np.random.default_rng(2)
    shifted = [p + rng.uniform(0.05, 0.10, 3).astype(np.float32) * rng.choice([-1, 1], 3) for p in _originals(street)]
    good = KissOdometryMetric().compute(_seq(street, _originals(street)))
    bad = KissOdometryMetric().compute(_seq(street, shifted))
    assert bad["kiss_failed"] == 0
    assert bad["kiss_rpe_trans"] > max(0.05, 3 * good["kiss_rpe_trans"])


def test_a_kiss_icp_failure_is_a_value_not_a_crash(street, monkeypatch):
    class Broken:
        last_pose = np.eye(4)

        def register_frame(self, frame, timestamps):
            raise RuntimeError("ICP diverged")

    monkeypatch.setattr(kiss, "_pipeline", lambda max_range, settings: Broken())
    out = KissOdometryMetric().compute(_seq(street, _originals(street)))
    assert out["kiss_failed"] == 1.0
    assert all(out[i] is None for i in KissOdometryMetric.ids if i != "kiss_failed")


def test_non_finite_poses_are_a_failure(street, monkeypatch):
    class Diverged:
        last_pose = np.full((4, 4), np.nan)

        def register_frame(self, frame, timestamps):
            return frame, frame

    monkeypatch.setattr(kiss, "_pipeline", lambda max_range, settings: Diverged())
    assert KissOdometryMetric().compute(_seq(street, _originals(street)))["kiss_failed"] == 1.0


def test_empty_decoded_scans_do_not_crash(street):
    empty = [np.zeros((0, 3), np.float32)] * len(street)
    out = KissOdometryMetric().compute(_seq(street, empty))
    # Nothing to register: KISS-ICP stays at the first pose; the error is the distance driven.
    assert out["kiss_failed"] == 0 and out["kiss_ate_rmse"] > 1.0


def test_single_frame_gives_none(street):
    out = KissOdometryMetric().compute(SequenceEvaluation(street, [0], [street[0].points], "one", {}))
    assert out["kiss_ate_rmse"] is None and out["kiss_failed"] == 0


def test_environment_does_not_change_the_settings(street, monkeypatch):
    """KISS-ICP's config is a pydantic BaseSettings (KISS_ICP_* variables): explicit values win."""
    monkeypatch.setenv("KISS_ICP_OUT_DIR", "/nonexistent")
    monkeypatch.setenv("KISS_ICP_DATA", '{"max_range": 1.0}')
    pipeline = kiss._pipeline(60.0, KISS_SETTINGS)
    assert pipeline.config.data.max_range == 60.0
    assert pipeline.config.mapping.voxel_size == pytest.approx(0.6)
