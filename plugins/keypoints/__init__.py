"""``harris3d``, ``iss``, ``sift3d``: the PCL keypoint detectors PocoNet compares against.

PocoNet (§IV-B, Tables I-II) keeps 8,000-10,000 points of a KITTI scan with Harris-3D, SIFT-3D
and ISS from PCL and with random sampling (``plugins/random``). Here each detector is a
budgeted :class:`~lwbench.SelectionCodec`: it ranks every point (its own keypoints first) and
keeps exactly ``points`` / ``ratio`` of the scan, so all selectors spend the same bytes.
All neighbourhood work is vectorized over the whole scan (``_geometry``).
"""

from __future__ import annotations

from lwbench import hookimpl

from ._base import KeypointError, KeypointSelector
from .harris import Harris3D
from .iss import ISS
from .sift import SIFT3D

__all__ = ["Harris3D", "ISS", "SIFT3D", "KeypointError", "KeypointSelector"]


@hookimpl
def lwbench_codecs() -> list[type[KeypointSelector]]:
    return [Harris3D, ISS, SIFT3D]
