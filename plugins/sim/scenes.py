"""The scene registry: name -> builder. Every builder is a pure function of a ``numpy`` generator,
so the same seed rebuilds the same world on any machine.

Sizes follow what the papers describe: the VSGP paper's mine tunnel (~135 m long, varying width,
height and ground elevation), a KITTI-like street for PocoNet's localization protocol, and an
indoor floor like the VSGP lab demo. The town is the street scene at scale: a 2 km drive through
a grid of blocks (2,051 HDL-64E scans), for full-length sequences.
"""

from __future__ import annotations

from collections.abc import Callable

from .base import Scene
from .indoor import build_indoor
from .town import build_town
from .tunnel import build_tunnel
from .urban import build_urban

__all__ = ["SCENES", "Scene"]

# Each builder takes the scene's generator and, as ``day``, a generator for what changes between
# two drives through the same place (only the street and the town have such things: parked cars).
SCENES: dict[str, Callable[..., Scene]] = {
    "tunnel": build_tunnel,
    "urban": build_urban,
    "indoor": build_indoor,
    "town": build_town,
}
