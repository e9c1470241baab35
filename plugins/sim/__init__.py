"""``sim``: the built-in LiDAR simulator, lwbench's default dataset.

Ray-casts a sensor model (VLP-16, HDL-64E, OS1-128 or any beam table) through procedural
scenes -- a mine tunnel, a KITTI-like street, an indoor floor -- along a ground-truth path, with
range noise, dropouts, intensity, ring and per-point time. No download needed: a fresh install
can benchmark codecs right away, and ``lwbench simulate`` writes a sequence out in KITTI layout.
"""

from __future__ import annotations

from lwbench import hookimpl

from .dataset import SIM_VERSION, SimDataset

__all__ = ["SimDataset", "SIM_VERSION"]


@hookimpl
def lwbench_datasets() -> list[type[SimDataset]]:
    return [SimDataset]
