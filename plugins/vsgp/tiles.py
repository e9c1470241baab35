"""Which inducing points each tile's GP holds: its own and its halo (``grid.halo_members``),
computed from a payload's body alone, so the encoder fits and the decoder predicts with the
same sets."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lwbench import SensorModel

from .grid import Tiling, halo_cols, halo_members
from .wire import Body, dequantize_azimuth

__all__ = ["Points", "gather_points", "tile_members"]


@dataclass
class Points:
    """Every inducing point of a body, concatenated in tile order."""

    tile_of: np.ndarray  # (M,) tile index
    beam: np.ndarray  # (M,) row
    az: np.ndarray  # (M,) GP azimuth (rad)
    colpos: np.ndarray  # (M,) column position in [0, n_cols)
    start: np.ndarray  # (T + 1,) offsets of each tile's points


def gather_points(body: Body, sensor: SensorModel) -> Points:
    counts = np.array([len(t.az_code) for t in body.tiles], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts)])
    if start[-1] == 0:
        z = np.zeros(0)
        return Points(np.zeros(0, np.int64), np.zeros(0, np.int64), z, z, start)
    az = dequantize_azimuth(np.concatenate([t.az_code for t in body.tiles]))
    beam = np.concatenate([t.beam for t in body.tiles]).astype(np.int64)
    colpos = np.mod((az - sensor.azimuths_rad()[0]) / sensor.azimuth_step_rad, sensor.n_azimuth)
    return Points(np.repeat(np.arange(len(body.tiles)), counts), beam, az, colpos, start)


def _neighbours(tiling: Tiling, t: int) -> list[int]:
    """Tiles whose points can be in ``t``'s halo: the adjacent sectors (a halo reaches at most a
    sector's width) of the same and the adjacent bands (it reaches ``HALO_ROWS`` < 16 beams)."""
    band, sector = tiling.tile(t)
    out = set()
    for b in range(max(0, band - 1), min(tiling.n_bands, band + 2)):
        for ds in (-1, 0, 1):
            out.add(b * tiling.n_sectors + (sector + ds) % tiling.n_sectors)
    out.discard(t)
    return sorted(out)


def tile_members(body: Body, sensor: SensorModel, pts: Points, t: int) -> np.ndarray:
    """Indices (into ``pts``) of tile ``t``'s GP inputs: its own points first, then its halo."""
    own = np.arange(pts.start[t], pts.start[t + 1])
    tiling = body.tiling
    if tiling.n_tiles == 1:
        return own
    reach = halo_cols(body.tiles[t].hyper[0], sensor.azimuth_step_rad, tiling)
    cand = np.concatenate([np.arange(pts.start[n], pts.start[n + 1]) for n in _neighbours(tiling, t)])
    keep = halo_members(tiling, t, pts.tile_of[cand], pts.beam[cand], pts.colpos[cand], reach)
    return np.concatenate([own, cand[keep]])
