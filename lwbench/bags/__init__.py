"""ROS bags in and out, with the ``rosbags`` library (pure Python; no ROS install).

- :class:`BagDataset` (dataset ``rosbag``, registered through the ``lwbench`` entry point
  ``bags`` like every loader): PointCloud2 scans from ``.db3`` / ``.mcap`` / rosbag2 folders
  and ROS 1 ``.bag`` files, poses from tf or odometry;
- :func:`write_bag`: clouds (decoded ones, by ``lwbench decode --format bag``) back into a bag
  on their topics and stamps.

``rosbags`` is imported only when a bag is opened, so ``lwbench list`` stays fast.
"""

from __future__ import annotations

from lwbench.hookspecs import hookimpl

from .reader import BAG_SUFFIXES, SENSOR_TOPIC, BagDataset
from .writer import BAG_STORAGES, DEFAULT_TOPIC, BagCloud, frames_to_clouds, write_bag

__all__ = [
    "BAG_STORAGES",
    "BAG_SUFFIXES",
    "BagCloud",
    "BagDataset",
    "DEFAULT_TOPIC",
    "SENSOR_TOPIC",
    "frames_to_clouds",
    "write_bag",
]


@hookimpl
def lwbench_datasets() -> list[type[BagDataset]]:
    return [BagDataset]
