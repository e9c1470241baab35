"""The occupancy map moved into core (the stream's base builds it too): :mod:`lwbench.occupancy`.

Kept so that ``lwbench_metrics.occupancy`` keeps importing; new code imports from ``lwbench``.
"""

from __future__ import annotations

from lwbench import OCCUPANCY_PARAMS, OccupancyMap, compare_occupancy, occupied_voxels
from lwbench.geometry import voxel_keys

__all__ = ["OCCUPANCY_PARAMS", "OccupancyMap", "compare_occupancy", "occupied_voxels", "voxel_keys"]
