"""Voxel selector: at most one real point per voxel, every occupied voxel kept, deterministic."""

from __future__ import annotations

import numpy as np
import pytest
from lwbench_plugins.voxel import VoxelSelector, voxel_keys

from lwbench import Frame, Payload, PayloadError, get_sensor, pack_points


def scan(n: int = 30_000, seed: int = 0) -> Frame:
    rng = np.random.default_rng(seed)
    # Clustered like a real scan: dense near the sensor, sparse far away, negative coordinates.
    r = rng.exponential(8.0, n) + 0.5
    az = rng.uniform(-np.pi, np.pi, n)
    z = rng.uniform(-2, 2, n)
    pts = np.stack([r * np.cos(az), r * np.sin(az), z], axis=1)
    return Frame(pts.astype(np.float32), get_sensor("hdl64e"))


def floor_cells(points: np.ndarray, size: float) -> np.ndarray:
    """Voxel indices computed independently of the codec's key packing."""
    return np.floor(points.astype(np.float64) / size).astype(np.int64)


@pytest.mark.parametrize("size", [0.05, 0.2, 1.0])
@pytest.mark.parametrize("keep", ["centroid", "center"])
def test_one_point_per_occupied_voxel(size: float, keep: str) -> None:
    frame = scan()
    idx = VoxelSelector(voxel_size=size, keep=keep).select(frame)
    assert idx.dtype.kind == "i" and np.all(np.diff(idx) > 0)  # sorted, unique, real indices
    kept = floor_cells(frame.points[idx], size)
    all_cells = np.unique(floor_cells(frame.points, size), axis=0)
    assert len(np.unique(kept, axis=0)) == len(kept)  # <= 1 point per voxel
    assert len(kept) == len(all_cells)  # and every occupied voxel keeps one
    assert len(idx) < len(frame)


def test_keeps_the_point_nearest_the_centroid() -> None:
    pts = np.array(
        [[0.1, 0.1, 0.1], [0.9, 0.9, 0.9], [0.45, 0.5, 0.55], [0.2, 0.8, 0.4],  # voxel (0,0,0)
         [1.05, 0.0, 0.0]],  # voxel (1,0,0), alone
        dtype=np.float32,
    )
    frame = Frame(pts, get_sensor("vlp16"))
    np.testing.assert_array_equal(VoxelSelector(voxel_size=1.0).select(frame), [2, 4])
    # Nearest the voxel centre (0.5, 0.5, 0.5) is also point 2; move the centroid away from it.
    pts2 = np.concatenate([pts, np.full((6, 3), 0.95, np.float32)])
    frame2 = Frame(pts2, get_sensor("vlp16"))
    assert 2 not in VoxelSelector(voxel_size=1.0).select(frame2)
    assert 2 in VoxelSelector(voxel_size=1.0, keep="center").select(frame2)


def test_matches_a_reference_loop_on_a_small_scan() -> None:
    frame = scan(2_000, seed=4)
    size = 0.5
    cells = floor_cells(frame.points, size)
    expected = []
    for cell in np.unique(cells, axis=0):
        members = np.flatnonzero((cells == cell).all(axis=1))
        centroid = frame.points[members].astype(np.float64).mean(axis=0)
        d = ((frame.points[members] - centroid) ** 2).sum(axis=1)
        expected.append(members[np.argmin(d)])
    np.testing.assert_array_equal(VoxelSelector(voxel_size=size).select(frame), np.sort(expected))


def test_deterministic_and_serialized_with_the_shared_serializer() -> None:
    frame = scan(seed=1)
    a, b = VoxelSelector(voxel_size=0.3), VoxelSelector(voxel_size=0.3)
    data = a.encode(frame)
    assert data == b.encode(frame)
    idx = a.select(frame)
    assert Payload.from_bytes(data).body == pack_points(frame.points[idx], "float32")
    np.testing.assert_array_equal(VoxelSelector().decode(data), frame.points[idx])
    quant = VoxelSelector(voxel_size=0.3, encoding="quantized", quant_step=0.01).encode(frame)
    assert len(quant) < len(data)
    assert np.abs(VoxelSelector().decode(quant) - frame.points[idx]).max() <= 0.005 + 1e-5
    with pytest.raises(PayloadError):
        VoxelSelector().decode(data[:-3])


def test_keys_are_collision_free_and_reject_huge_extents() -> None:
    frame = scan(seed=2)
    keys = voxel_keys(frame.points, 0.1)
    cells = floor_cells(frame.points, 0.1)
    assert len(np.unique(keys)) == len(np.unique(cells, axis=0))
    with pytest.raises(ValueError):
        voxel_keys(np.array([[0, 0, 0], [1e6, 0, 0]], np.float32), 0.1)


def test_empty_scan() -> None:
    frame = Frame(np.zeros((0, 3), np.float32), get_sensor("vlp16"))
    assert len(VoxelSelector().select(frame)) == 0
    assert VoxelSelector().decode(VoxelSelector().encode(frame)).shape == (0, 3)
