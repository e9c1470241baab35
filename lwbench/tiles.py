"""Voxel maps of a whole drive in bounded memory: tiles kept on disk when the route has left them.

A drive of thousands of scans covers kilometres: at 5 cm a town's occupancy map has tens of
millions of voxels (21,000 more per metre of street on the simulated HDL-64E street), far more
than a laptop should hold -- and a voxel map's memory grows with the area, which grows with the
route. Every sequence metric's map is therefore cut into square **tiles** (:data:`TILE_M` on a
side, in the horizontal plane) by voxel key, and a :class:`SpillingTiles` keeps the tiles the
route is near in memory (within a byte budget, least recently used out first) and writes the
others to a scratch folder, to be read back when the route returns (a loop) or when the map is
finished tile by tile.

A scan reaches only the tiles within its range of the sensor (:func:`tiles_near`), so the working
set is a few tiles whatever the length of the drive; what is on disk grows with the area.
Nothing here changes a value: tiles partition the voxels, and each tile's arrays are what the
whole map's would hold for those voxels.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Generic, Protocol, TypeVar

import numpy as np

from lwbench.geometry import voxel_indices, voxel_keys

__all__ = [
    "TILE_M", "SpillingTiles", "neighbours", "split_by_tile", "tile_budget_bytes", "tile_ids", "tiles_at", "tiles_near",
]

#: Tile side, metres: a few tiles cover a scan's reach (30 m for the occupancy map), and a tile
#: of 5 cm voxels along a street holds ~0.7 M voxels (17 MB of keys and counts).
TILE_M = 32.0


def tile_budget_bytes() -> int:
    """The most one map keeps in memory (``LWBENCH_MAP_MEMORY_MB``, default 256 MB); the rest
    spills. Tiles the route has left go out sooner (:attr:`SpillingTiles.idle`)."""
    return int(float(os.environ.get("LWBENCH_MAP_MEMORY_MB", "256")) * 2**20)


#: A tile no scan has touched for this many scans is written out whatever the budget: memory is
#: then what the last scans reach (their working set), not what the budget allows.
IDLE_SCANS = 8


def _voxels_per_tile(voxel: float) -> int:
    return max(1, int(round(TILE_M / voxel)))


_HALF = 1 << 31  # tile indices are signed; an id packs them shifted to non-negative


def _tile_id(tx, ty):
    return ((np.asarray(tx, dtype=np.int64) + _HALF) << 32) | (np.asarray(ty, dtype=np.int64) + _HALF)


def tile_ids(keys: np.ndarray, voxel: float) -> np.ndarray:
    """The tile of each world voxel key (:func:`lwbench.geometry.voxel_keys`): tile ``(tx, ty)``
    holds the voxels with ``tx * n <= ix < (tx + 1) * n`` (and so for y), ``n`` voxels a side."""
    n = _voxels_per_tile(voxel)
    idx = voxel_indices(keys)
    return _tile_id(idx[:, 0] // n, idx[:, 1] // n)


def tiles_at(points: np.ndarray, voxel: float) -> np.ndarray:
    """The tile of each world point (x, y; z is ignored): a caller that picks regions in metres
    finds which tiles hold them without knowing how tiles are numbered."""
    pts = np.asarray(points, dtype=np.float64)
    xyz = np.zeros((len(pts), 3))
    xyz[:, :2] = pts[:, :2]
    return tile_ids(voxel_keys(xyz, voxel), voxel)


def neighbours(tile: int) -> list[int]:
    """The eight tiles around ``tile``."""
    tx, ty = (tile >> 32) - _HALF, (tile & 0xFFFFFFFF) - _HALF
    return [int(_tile_id(tx + dx, ty + dy)) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]


def split_by_tile(keys: np.ndarray, voxel: float, *arrays: np.ndarray) -> Iterator[tuple[int, tuple[np.ndarray, ...]]]:
    """``(tile, (keys, *arrays) of that tile)`` for sorted keys, each tile's rows in key order."""
    if len(keys) == 0:
        return
    tiles = tile_ids(keys, voxel)
    order = np.argsort(tiles, kind="stable")  # stable: each tile keeps the keys' order
    tiles = tiles[order]
    cuts = np.flatnonzero(np.diff(tiles)) + 1
    for lo, hi in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(tiles)]]), strict=True):
        rows = order[lo:hi]
        yield int(tiles[lo]), (keys[rows], *(a[rows] for a in arrays))


def tiles_near(centre: np.ndarray, radius: float, voxel: float) -> list[int]:
    """Every tile with a voxel within ``radius`` (horizontally) of ``centre``."""
    n = _voxels_per_tile(voxel)

    def span(c: float) -> range:
        return range(math.floor((c - radius) / voxel) // n, math.floor((c + radius) / voxel) // n + 1)

    return [int(_tile_id(tx, ty)) for tx in span(float(centre[0])) for ty in span(float(centre[1]))]


class Tile(Protocol):
    def nbytes(self) -> int: ...

    def arrays(self) -> dict[str, np.ndarray]: ...


T = TypeVar("T", bound=Tile)


class SpillingTiles(Generic[T]):
    """Tiles of one map: at most ``budget`` bytes in memory, the rest as ``.npz`` files in a
    scratch folder (removed by :meth:`close`). ``make()`` builds an empty tile, ``load(arrays)``
    one from what :meth:`Tile.arrays` gave when it was written out."""

    def __init__(self, make: Callable[[], T], load: Callable[[dict[str, np.ndarray]], T],
                 budget: int | None = None, name: str = "map") -> None:
        self.make, self.load = make, load
        self.budget = tile_budget_bytes() if budget is None else budget
        self.name = name
        self._memory: OrderedDict[int, T] = OrderedDict()
        self._used: dict[int, int] = {}  # tile -> the settle() count when it was last asked for
        self._tick = 0
        self.idle = IDLE_SCANS
        self._on_disk: set[int] = set()
        self._folder: Path | None = None
        self.spilled = 0  # tiles written out (a figure for the docs and tests)

    neighbours = staticmethod(neighbours)

    def __contains__(self, tile: int) -> bool:
        return tile in self._memory or tile in self._on_disk

    def tiles(self) -> list[int]:
        return sorted(set(self._memory) | self._on_disk)

    def get(self, tile: int, create: bool = True) -> T | None:
        """The tile (read back from disk if it was written out; a new one if ``create``)."""
        self._used[tile] = self._tick
        item = self._memory.get(tile)
        if item is not None:
            self._memory.move_to_end(tile)
            return item
        if tile in self._on_disk:
            path = self._path(tile)
            with np.load(path) as data:
                item = self.load({k: data[k] for k in data.files})
            path.unlink()
            self._on_disk.discard(tile)
        elif create:
            item = self.make()
        else:
            return None
        self._memory[tile] = item
        return item

    def settle(self) -> None:
        """Once per scan, after its updates (a tile grows while it is updated): write out the
        tiles no scan asked for in the last :attr:`idle` scans, then the least recently used
        ones until the rest fit the budget."""
        self._tick += 1
        total = sum(t.nbytes() for t in self._memory.values())
        while self._memory and len(self._memory) > 1:
            tile = next(iter(self._memory))
            if total <= self.budget and self._tick - self._used.get(tile, 0) <= self.idle:
                break
            item = self._memory.pop(tile)
            total -= item.nbytes()
            np.savez(self._path(tile), **item.arrays())
            self._on_disk.add(tile)
            self.spilled += 1

    def drain(self) -> Iterator[tuple[int, T]]:
        """Every tile once, in tile order, each dropped from the map after it is yielded."""
        for tile in self.tiles():
            item = self.get(tile, create=False)
            self._memory.pop(tile, None)
            yield tile, item

    def _path(self, tile: int) -> Path:
        if self._folder is None:
            self._folder = Path(tempfile.mkdtemp(prefix=f"lwbench-{self.name}-", dir=os.environ.get("LWBENCH_SCRATCH")))
        return self._folder / f"{tile:x}.npz"

    def close(self) -> None:
        self._memory.clear()
        self._on_disk.clear()
        if self._folder is not None:
            shutil.rmtree(self._folder, ignore_errors=True)
            self._folder = None

    def __enter__(self) -> SpillingTiles[T]:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
