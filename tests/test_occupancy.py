"""Occupancy fidelity: log-odds voxel maps with ray-cast free space, decoded vs original."""

from __future__ import annotations

import numpy as np
import pytest
from _task_scene import TEST32, StreetDataset
from lwbench_metrics.task import OccupancyMetric

from lwbench import SensorModel, SequenceEvaluation, compare_occupancy, occupied_voxels
from lwbench.geometry import voxel_keys

OCC_IDS = {"occ_iou", "occ_precision", "occ_recall"}


@pytest.fixture(scope="module")
def street() -> StreetDataset:
    return StreetDataset(n=6, seed=1)


def _seq(ds, decoded, name="test"):
    return SequenceEvaluation(ds, list(range(len(ds))), decoded, name, {})


def _originals(ds):
    return [ds[i].points for i in range(len(ds))]


def test_ids_and_resolutions():
    assert OCC_IDS <= set(OccupancyMetric.ids)
    assert {"occ_iou_005", "occ_precision_005", "occ_recall_005"} <= set(OccupancyMetric.ids)


def test_identical_clouds_score_one(street):
    out = OccupancyMetric().compute(_seq(street, _originals(street)))
    assert set(out) == set(OccupancyMetric.ids)
    assert all(v == 1.0 for v in out.values())


def test_shifted_clouds_score_lower_and_more_so_at_fine_resolution(street):
    shifted = [p + np.float32([0.15, 0.0, 0.0]) for p in _originals(street)]
    out = OccupancyMetric().compute(_seq(street, shifted, "shifted"))
    assert out["occ_iou"] < 0.9
    assert out["occ_iou_005"] < out["occ_iou"]
    assert out["occ_iou_005"] < 0.5


def test_subsampled_clouds_keep_precision_but_lose_recall(street):
    rng = np.random.default_rng(0)
    sub = [p[rng.random(len(p)) < 0.05] for p in _originals(street)]
    out = OccupancyMetric().compute(_seq(street, sub, "random5"))
    assert out["occ_precision"] > 0.8  # what is left is in the right place ...
    assert out["occ_recall"] < 0.5  # ... but most occupied voxels are missing
    assert out["occ_iou"] == pytest.approx(
        1 / (1 / out["occ_precision"] + 1 / out["occ_recall"] - 1), rel=1e-9
    )


def test_free_space_clears_a_ghost_in_front_of_a_wall():
    """A voxel hit once but seen through by later scans is not occupied; the wall stays occupied."""
    sensor = SensorModel("flat", (0.0,), 1.0, 0.1, 50.0, 10.0)  # one beam, 360 rays
    az = np.radians(np.arange(-20, 21))  # rays towards a wall at x = 10
    wall = np.stack([np.full(az.shape, 10.0), 10.0 * np.tan(az), np.zeros_like(az)], axis=1)
    ghost = wall.copy()
    ghost[20] = [5.0, 0.0, 0.0]  # the straight-ahead ray once returns at 5 m (e.g. a passing bird)
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, :3, 3] = [0.03, 0.07, 0.09]  # keep the rays off voxel faces
    occ = occupied_voxels([ghost, wall, wall, wall], poses, sensor, 0.2)
    ghost_key = voxel_keys(np.array([[5.0, 0.0, 0.0]]) + poses[0, :3, 3], 0.2)
    wall_keys = voxel_keys(wall + poses[0, :3, 3], 0.2)
    assert not np.isin(ghost_key, occ).any()
    assert np.isin(wall_keys, occ).all()
    # Seen only once and never contradicted, the ghost would be occupied.
    assert np.isin(ghost_key, occupied_voxels([ghost], poses[:1], sensor, 0.2)).all()


def test_a_voxel_behind_the_hit_is_not_cleared():
    sensor = SensorModel("flat", (0.0,), 1.0, 0.1, 50.0, 10.0)
    far = np.array([[10.0, 0.0, 0.0]])
    near = np.array([[6.0, 0.0, 0.0]])
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, :3, 3] = [0.03, 0.07, 0.09]
    occ = occupied_voxels([far, near], poses, sensor, 0.2)
    assert np.isin(voxel_keys(far + poses[0, :3, 3], 0.2), occ).all()  # occluded by the nearer hit


def test_compare_occupancy_edge_cases():
    a = np.array([1, 2, 3, 4], dtype=np.int64)
    assert compare_occupancy(a, a) == {"iou": 1.0, "precision": 1.0, "recall": 1.0}
    out = compare_occupancy(a, np.array([3, 4, 5, 6, 7, 8], dtype=np.int64))
    assert out == {"iou": 2 / 8, "precision": 2 / 6, "recall": 2 / 4}
    empty = np.zeros(0, np.int64)
    assert compare_occupancy(a, empty) == {"iou": 0.0, "precision": None, "recall": 0.0}
    assert compare_occupancy(empty, empty) == {"iou": None, "precision": None, "recall": None}


def test_out_of_grid_points_raise():
    with pytest.raises(ValueError):
        voxel_keys(np.array([[1e9, 0.0, 0.0]]), 0.05)


def test_test_sensor_is_street_sized():
    assert TEST32.max_range >= 50


@pytest.mark.heavy
def test_the_live_map_equals_the_batch_map_in_any_order(street):
    """What lwbench stream's base keeps: one insert per received scan, the same map exactly."""
    from lwbench import OccupancyMap

    scans, poses, sensor = _originals(street), np.stack([street[i].pose for i in range(len(street))]), TEST32
    for voxel in (0.2, 0.05):
        expected = occupied_voxels(scans, poses, sensor, voxel)
        for order in (range(len(scans)), np.random.default_rng(3).permutation(len(scans))):
            live = OccupancyMap(sensor, voxel)
            for i in order:
                live.insert(scans[i], poses[i])
            assert np.array_equal(live.occupied(), expected)
        partial = OccupancyMap(sensor, voxel)
        for i in (4, 1):
            partial.insert(scans[i], poses[i])
        assert np.array_equal(partial.occupied(), occupied_voxels([scans[4], scans[1]], poses[[4, 1]], sensor, voxel))
    assert len(OccupancyMap(sensor).occupied()) == 0
