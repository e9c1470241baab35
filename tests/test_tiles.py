"""Maps of a whole drive in tiles: a map whose tiles went to disk is the map held in memory --
the occupancy keys exactly, the localization map's centroids exactly and its normals (estimated
tile by tile with a halo of the neighbours) to rounding."""

from __future__ import annotations

import numpy as np
import pytest
from lwbench_metrics.localization import ICP_PARAMS, MapBuilder

from lwbench import SpillingTiles, occupancy_maps, split_by_tile, tiles_near
from lwbench.geometry import voxel_keys
from lwbench.registry import get_registry


@pytest.fixture(scope="module")
def street():
    ds = get_registry().dataset("sim")(scene="urban", frames=12, cache=False)
    return [(f.points, f.pose) for f in ds], ds.sensor


def test_tiles_partition_the_keys_and_a_scan_reaches_the_tiles_near_it():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-100, 100, (5000, 3))
    keys = np.unique(voxel_keys(pts, 0.2))
    parts = list(split_by_tile(keys, 0.2))
    assert sum(len(k) for _, (k,) in parts) == len(keys)
    assert np.array_equal(np.sort(np.concatenate([k for _, (k,) in parts])), keys)
    assert all(np.all(np.diff(k) > 0) for _, (k,) in parts)  # each tile in key order
    centre = np.array([3.0, -7.0, 0.0])
    near = set(tiles_near(centre, 30.0, 0.2))
    close = np.linalg.norm(pts[:, :2] - centre[:2], axis=1) <= 30.0
    close_keys = np.unique(voxel_keys(pts[close], 0.2))
    assert {t for t, _ in split_by_tile(close_keys, 0.2)} <= near


@pytest.mark.heavy
def test_an_occupancy_map_spilled_to_disk_is_the_one_held_in_memory(street, monkeypatch):
    scans, sensor = street

    def passes(what):
        return iter(scans)

    monkeypatch.setenv("LWBENCH_MAP_MEMORY_MB", "4096")
    held = occupancy_maps(passes, sensor)
    monkeypatch.setenv("LWBENCH_MAP_MEMORY_MB", "0.01")
    spilled = occupancy_maps(passes, sensor)
    for v in held:
        assert len(held[v]) > 1000 and np.array_equal(held[v], spilled[v])


@pytest.mark.heavy
def test_a_localization_map_spilled_to_disk_is_the_one_held_in_memory(street):
    scans, _ = street
    maps = []
    for budget in (1 << 40, 1):
        builder = MapBuilder(ICP_PARAMS["map_voxel"], budget=budget)
        if budget > 1:
            builder.tiles.idle = 10**9  # held: nothing goes out, not even the tiles the route left
        for points, pose in scans:
            builder.add(points, pose)
        maps.append(builder.finish(ICP_PARAMS))
    held, spilled = maps
    assert spilled.tiles.spilled > 0 and held.tiles.spilled == 0
    assert len(held) == len(spilled) > 1000
    centre = scans[6][1][:3, 3]
    a, b = held.cloud(around=(centre, 40.0)), spilled.cloud(around=(centre, 40.0))
    assert np.array_equal(np.asarray(a.points), np.asarray(b.points))
    na, nb = np.asarray(a.normals), np.asarray(b.normals)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", na, nb)), 1.0, atol=1e-9)  # same planes (a sign may flip)
    for m in maps:
        m.close()


def test_tiles_the_route_has_left_go_out_whatever_the_budget(street):
    """Memory follows what the last scans reach: a long drive's map is mostly on disk even under a
    budget that would hold all of it."""
    scans, _ = street
    builder = MapBuilder(ICP_PARAMS["map_voxel"], budget=1 << 40)
    for points, pose in scans:
        builder.add(points, pose)
    builder.tiles.idle = 2
    for points, pose in scans[-3:]:
        builder.add(points, pose)
    held = len(builder.tiles._memory)
    assert builder.tiles.spilled > 0 and held < len(builder.tiles.tiles())
    builder.tiles.close()


def test_spilled_tiles_are_removed_on_close(tmp_path, monkeypatch):
    monkeypatch.setenv("LWBENCH_SCRATCH", str(tmp_path))

    class Box:
        def __init__(self, a=None):
            self.a = np.zeros(1000) if a is None else a

        def nbytes(self):
            return self.a.nbytes

        def arrays(self):
            return {"a": self.a}

    tiles = SpillingTiles(Box, lambda d: Box(d["a"]), budget=10_000)
    for t in range(5):
        tiles.get(t).a[:] = t
        tiles.settle()
    assert tiles.spilled >= 3 and any(tmp_path.iterdir())
    assert [float(tiles.get(t).a[0]) for t in range(5)] == [0.0, 1.0, 2.0, 3.0, 4.0]
    tiles.close()
    assert not any(tmp_path.iterdir())
