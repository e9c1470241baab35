"""An office floor like the VSGP paper's lab demo: an L-shaped corridor lined with rooms.

A 2.2 m wide main corridor (36 m) with a branch (19 m) at its far end; rooms of random width on
both sides, each with a 1 m door onto the corridor (some open, so the sensor sees furniture in
the room, some closed); desks, cabinets and chairs in the rooms and a few objects along the
corridor walls. A Jackal-like robot with the VSGP paper's VLP-16 (10 m range, 4 Hz) at 0.5 m
drives down the corridor and turns into the branch at 0.5 m/s.
"""

from __future__ import annotations

import numpy as np

from .base import Scene
from .mesh import Material, MeshBuilder
from .trajectory import Path, waypoint_path

WALL = Material(0.6)
FLOOR = Material(0.3)
CEILING = Material(0.7)
DOOR = Material(0.4)
HEIGHT = 2.8
THICK = 0.12
HALF = 1.1  # corridor half width
DOOR_W = 1.0


def _split(rng: np.random.Generator, lo: float, hi: float) -> np.ndarray:
    """Room boundaries between ``lo`` and ``hi``, rooms 3.5-7 m wide."""
    cuts = [lo]
    while hi - cuts[-1] > 7.0:  # the last room is 3.5-7 m too
        cuts.append(cuts[-1] + rng.uniform(3.5, min(6.5, hi - cuts[-1] - 3.5)))
    cuts.append(hi)
    return np.array(cuts)


def build_indoor(rng: np.random.Generator, day: np.random.Generator | None = None) -> Scene:
    b = MeshBuilder()
    x_end, bx0, bx1, y_end = 36.0, 30.0, 30.0 + 2 * HALF, 20.0
    depth = 6.4
    # rooms: (x0, x1, y0, y1, door side: the wall facing the corridor)
    rooms: list[tuple[float, float, float, float, str]] = []
    for a, c in zip((cuts := _split(rng, 0.0, x_end))[:-1], cuts[1:], strict=True):
        rooms.append((a, c, -HALF - depth, -HALF, "y1"))
    for a, c in zip((cuts := _split(rng, 0.0, bx0))[:-1], cuts[1:], strict=True):
        rooms.append((a, c, HALF, HALF + depth, "y0"))
    for a, c in zip((cuts := _split(rng, HALF + depth, y_end))[:-1], cuts[1:], strict=True):
        rooms.append((bx0 - depth, bx0, a, c, "x1"))
    for a, c in zip((cuts := _split(rng, HALF, y_end))[:-1], cuts[1:], strict=True):
        rooms.append((bx1, bx1 + depth, a, c, "x0"))
    walls: list[tuple[float, float, float, float]] = []  # axis-aligned wall rectangles (x0, x1, y0, y1)
    doors: list[tuple[float, float, float, float]] = []
    for x0, x1, y0, y1, side in rooms:
        for edge in ("x0", "x1", "y0", "y1"):
            along_x = edge[0] == "y"
            fixed = {"x0": x0, "x1": x1, "y0": y0, "y1": y1}[edge]
            lo, hi = (x0, x1) if along_x else (y0, y1)
            spans = [(lo, hi)]
            if edge == side:
                d = rng.uniform(lo + 0.5, hi - 0.5 - DOOR_W)
                spans = [(lo, d), (d + DOOR_W, hi)]
                if rng.random() < 0.4:  # a closed door
                    doors.append(_rect(along_x, fixed, d + 0.02, d + DOOR_W - 0.02, 0.05))
            walls += [_rect(along_x, fixed, a, c, THICK) for a, c in spans if c - a > 1e-6]
        _furnish(b, rng, x0, x1, y0, y1, side)
    # Corridor ends.
    walls += [_rect(False, 0.0, -HALF, HALF, THICK), _rect(False, x_end, -HALF, HALF, THICK),
              _rect(True, y_end, bx0, bx1, THICK)]
    w = np.array(walls)
    b.boxes(np.column_stack([(w[:, 0] + w[:, 1]) / 2, (w[:, 2] + w[:, 3]) / 2, np.full(len(w), HEIGHT / 2)]),
            np.column_stack([w[:, 1] - w[:, 0], w[:, 3] - w[:, 2], np.full(len(w), HEIGHT)]), 0.0, WALL)
    if doors:
        d = np.array(doors)
        b.boxes(np.column_stack([(d[:, 0] + d[:, 1]) / 2, (d[:, 2] + d[:, 3]) / 2, np.full(len(d), 1.0)]),
                np.column_stack([d[:, 1] - d[:, 0], d[:, 3] - d[:, 2], np.full(len(d), 2.0)]), 0.0, DOOR)
    _corridor_objects(b, rng, x_end, bx0, bx1, y_end)
    lo, hi = (-1.0, -HALF - depth - 1.0), (x_end + depth + 1.0, y_end + 1.0)
    plane = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    b.add(plane, [[0, 1, 2], [0, 2, 3]], FLOOR)
    b.add(plane + [0, 0, HEIGHT], [[0, 1, 2], [0, 2, 3]], CEILING)
    mid = (bx0 + bx1) / 2
    path = Path(waypoint_path(np.array([[1.0, 0.0], [mid, 0.0], [mid, y_end - 1.0]]), radius=1.0, step=0.02))
    return Scene("indoor", b.build(), path, 0.5, 0.0, path.length - 0.2, "vlp16", 0.5)


def _rect(along_x: bool, fixed: float, a: float, c: float, thick: float) -> tuple[float, float, float, float]:
    if along_x:
        return (a, c, fixed - thick / 2, fixed + thick / 2)
    return (fixed - thick / 2, fixed + thick / 2, a, c)


def _furnish(b: MeshBuilder, rng: np.random.Generator, x0: float, x1: float, y0: float, y1: float,
             door_side: str) -> None:
    """Desks, cabinets and chairs, kept 1.2 m clear of the door wall."""
    n = int(rng.integers(2, 6))
    kinds = rng.integers(0, 3, n)
    sizes = np.array([[1.4, 0.7, 0.75], [0.5, 1.0, 1.9], [0.5, 0.5, 0.9]])[kinds]
    yaw = rng.choice([0.0, np.pi / 2], n)
    margin = 0.6
    lo = np.array([x0 + margin, y0 + margin])
    hi = np.array([x1 - margin, y1 - margin])
    axis = 0 if door_side[0] == "x" else 1
    if door_side[1] == "0":
        lo[axis] += 1.2
    else:
        hi[axis] -= 1.2
    xy = lo + rng.random((n, 2)) * np.maximum(hi - lo, 0.0)
    centres = np.column_stack([xy, sizes[:, 2] / 2])
    refl = np.column_stack([rng.uniform(0.25, 0.65, n), np.zeros(n)])
    b.boxes(centres, sizes, yaw, refl)


def _corridor_objects(b: MeshBuilder, rng: np.random.Generator, x_end: float, bx0: float, bx1: float,
                      y_end: float) -> None:
    """Cabinets, bins and boxes against the corridor walls, leaving the centre free."""
    n = 10
    along = rng.uniform(2.0, bx0 - 1.0, n)
    side = rng.choice([-1.0, 1.0], n)
    size = np.column_stack([rng.uniform(0.3, 0.9, n), rng.uniform(0.25, 0.35, n), rng.uniform(0.4, 1.8, n)])
    centres = np.column_stack([along, side * (HALF - THICK / 2 - size[:, 1] / 2), size[:, 2] / 2])
    m = 4
    up = rng.uniform(2.5, y_end - 1.5, m)
    side_b = rng.choice([0.0, 1.0], m)
    size_b = np.column_stack([rng.uniform(0.25, 0.35, m), rng.uniform(0.3, 0.9, m), rng.uniform(0.4, 1.8, m)])
    x = np.where(side_b > 0, bx1 - THICK / 2 - size_b[:, 0] / 2, bx0 + THICK / 2 + size_b[:, 0] / 2)
    centres_b = np.column_stack([x, up, size_b[:, 2] / 2])
    refl = np.column_stack([rng.uniform(0.3, 0.7, n + m), np.zeros(n + m)])
    b.boxes(np.vstack([centres, centres_b]), np.vstack([size, size_b]), 0.0, refl)
