"""``files``: the built-in loaders of scans on disk -- ``kitti`` (KITTI odometry folders and the
official ``sequences/NN`` tree) and ``files`` (a folder of PCD/PLY/XYZ/VTK/BIN scans, or one
scan file).

A plugin like any other: registered through the ``lwbench`` entry point ``files`` and built on
lwbench's public API only (``lwbench``: :class:`~lwbench.Dataset`, :func:`~lwbench.derive_sensor`;
``lwbench.io``: the readers), so a third-party loader can do all they do
(``examples/lwbench-example-loader``). See :mod:`.loaders` for the ``sensor`` parameter and
``sensor_guessed``, :mod:`.scan_picking` for which files of a folder are the scans.
"""

from __future__ import annotations

from lwbench import Dataset, hookimpl

from .loaders import FILES_LAYOUTS, KITTI_LAYOUTS, KittiDataset, PointFileDataset, SensorChoice
from .scan_picking import pick_scans

__all__ = ["KittiDataset", "PointFileDataset", "SensorChoice", "pick_scans", "KITTI_LAYOUTS", "FILES_LAYOUTS"]


@hookimpl
def lwbench_datasets() -> list[type[Dataset]]:
    return [KittiDataset, PointFileDataset]
