"""A procedural town: a long drive through a grid of city blocks, for full-length-sequence scale
runs and for varied streets (training data) from one seed.

The town is a grid of 6 x 6 crossings; the gaps between grid lines are drawn from 70-100 m and
every crossing is moved by up to 3 m, so blocks differ in size and streets kink slightly at
crossings. The route is a seeded walk over the crossings: at each one the car goes straight or
turns left or right (never back), preferring streets it has not driven yet, so most streets of
the route are distinct, but it may come back through a crossing it already passed (loops). Corners
are rounded with a 12 m radius (the urban corner's 15 m would take the inside of a right turn
over the curb corner where skewed streets make the turn sharper than 90 degrees). The walk goes
on until the driven lane has ``lead_in + drive + 60`` metres: at the scene's 10 m/s and the
HDL-64E's 10 Hz, 2,051 scans with the default ``drive``.

Every street of the grid has curbs, sidewalks (ending at the crossings, which stay open) and lane
paint. Each distinct street the route drives is furnished as the ``urban`` street is -- facades
with floor slabs, pilasters and glass, hedges and fences, lamp and sign poles, trees, parked cars
(from the ``day`` generator) and plain blocks behind the street front -- once, however often the
route drives it. Streets the route never drives are lined with plain blocks only (what the sensor
sees of them is their mouths, from the crossings). Nothing reaches into a street: lots, trees,
fences and blocks are tested against a KD-tree over every street's centre line and the route's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import Scene
from .mesh import MeshBuilder
from .trajectory import Path, waypoint_path
from .urban import (
    ASPHALT,
    CONCRETE,
    CURB_H,
    EGO_CAR,
    LANE,
    PAINT,
    ROAD_HALF,
    SIDEWALK,
    _backdrop,
    _buildings,
    _centre_dashes,
    _parked_cars,
    _poles,
    _trees,
)

GRID = 6  # crossings along each axis: 60 streets (grid edges) to choose from
SPACING = (70.0, 100.0)  # metres between neighbouring grid lines
JITTER = 3.0  # each crossing moved by up to this much along x and y
RADIUS = 12.0  # corner radius of the route's centre line (urban: 15 m, but its corner has no curb inside)
LEAD_IN = 60.0  # street behind the start, so the first scans see buildings behind the car
TAIL = 60.0  # street ahead of the last scan
FACADE = ROAD_HALF + SIDEWALK + 0.5  # the urban scene's facade line
# Walk weights of going straight, turning left, turning right at a crossing, and the factor for a
# street the route has already driven (so it drives one again mostly where every other way was).
TURN_WEIGHTS = (0.4, 0.3, 0.3)
DRIVEN_AGAIN = 0.05


@dataclass(frozen=True)
class TownPlan:
    """The town's layout: crossing positions ``nodes (GRID, GRID, 2)``, the route as the crossings
    it passes (``walk``, grid indices in driving order) and its streets (``edges``: each distinct
    street once, in the order first driven, as sorted pairs of grid indices)."""

    nodes: np.ndarray
    walk: tuple[tuple[int, int], ...]
    edges: tuple[tuple[tuple[int, int], tuple[int, int]], ...]
    centre: Path  # the route's centre line
    lane: Path  # the driven path: the right-hand lane, LANE metres right of the centre line

    def streets(self) -> list[tuple[tuple[int, int], tuple[int, int]]]:
        """Every street of the grid (driven or not), as sorted pairs of grid indices."""
        out = []
        for i in range(GRID):
            for j in range(GRID):
                if i + 1 < GRID:
                    out.append(((i, j), (i + 1, j)))
                if j + 1 < GRID:
                    out.append(((i, j), (i, j + 1)))
        return out


def _edge(a: tuple[int, int], b: tuple[int, int]) -> tuple[tuple[int, int], tuple[int, int]]:
    return (a, b) if a <= b else (b, a)


def plan_town(rng: np.random.Generator, length: float) -> TownPlan:
    """Draw the grid and walk it until the driven lane is at least ``length`` metres long and the
    route comes back through at least one crossing it passed before."""
    gaps = rng.uniform(*SPACING, size=(2, GRID - 1))
    xs = np.concatenate([[0.0], np.cumsum(gaps[0])])
    ys = np.concatenate([[0.0], np.cumsum(gaps[1])])
    nodes = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1) + rng.uniform(-JITTER, JITTER, (GRID, GRID, 2))
    for _ in range(100):  # (in practice the first walk already has a loop)
        walk, centre, lane = _walk(rng, nodes, length)
        if len(set(walk)) < len(walk):  # a loop: some crossing passed twice
            break
    edges = list(dict.fromkeys(_edge(a, b) for a, b in zip(walk[:-1], walk[1:], strict=True)))
    return TownPlan(nodes, tuple(walk), tuple(edges), centre, lane)


def _walk(rng: np.random.Generator, nodes: np.ndarray, length: float) -> tuple[list[tuple[int, int]], Path, Path]:
    start = (int(rng.integers(1, GRID - 1)), int(rng.integers(1, GRID - 1)))  # an inner crossing
    d = [(1, 0), (0, 1), (-1, 0), (0, -1)][int(rng.integers(4))]
    walk = [start, (start[0] + d[0], start[1] + d[1])]
    driven = {_edge(*walk)}
    while True:
        # The exact length once the walk is nearly long enough (rounded corners change it by metres).
        if _polyline_length(nodes, walk) >= length - 100.0:
            centre = Path(waypoint_path(np.array([nodes[n] for n in walk]), radius=RADIUS, step=0.1))
            lane = Path(centre.points + LANE * centre.lateral(centre.s))
            if lane.length >= length:
                return walk, centre, lane
        here, d = walk[-1], (walk[-1][0] - walk[-2][0], walk[-1][1] - walk[-2][1])
        moves, weights = [], []
        for k, (dx, dy) in enumerate((d, (-d[1], d[0]), (d[1], -d[0]))):  # straight, left, right
            nxt = (here[0] + dx, here[1] + dy)
            if 0 <= nxt[0] < GRID and 0 <= nxt[1] < GRID:
                moves.append(nxt)
                weights.append(TURN_WEIGHTS[k] * (DRIVEN_AGAIN if _edge(here, nxt) in driven else 1.0))
        p = np.array(weights) / sum(weights)
        nxt = moves[int(rng.choice(len(moves), p=p))]
        driven.add(_edge(here, nxt))
        walk.append(nxt)


def _polyline_length(nodes: np.ndarray, walk: list[tuple[int, int]]) -> float:
    pts = np.array([nodes[n] for n in walk])
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _street(nodes: np.ndarray, edge: tuple[tuple[int, int], tuple[int, int]], trim: float) -> Path:
    """A street's centre line from crossing to crossing, less ``trim`` metres at both ends."""
    a, b = nodes[edge[0]], nodes[edge[1]]
    u = (b - a) / np.linalg.norm(b - a)
    p, q = a + trim * u, b - trim * u
    n = max(2, int(np.linalg.norm(q - p) / 0.5) + 1)
    xy = p + np.linspace(0.0, 1.0, n)[:, None] * (q - p)
    return Path(np.column_stack([xy, np.zeros(n)]))


def build_town(rng: np.random.Generator, drive: float = 2050.0, day: np.random.Generator | None = None) -> Scene:
    """The town and a ``drive``-metre route through it; ``day`` draws the parked cars (what
    changes between two drives), everything else comes from ``rng`` alone."""
    day = day if day is not None else np.random.default_rng(rng.integers(2**63))
    plan = plan_town(rng, LEAD_IN + drive + TAIL)
    nodes, centre = plan.nodes, plan.centre
    b = MeshBuilder()
    lo = nodes.reshape(-1, 2).min(axis=0) - 150.0
    hi = nodes.reshape(-1, 2).max(axis=0) + 150.0
    ground = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    b.add(ground, [[0, 1, 2], [0, 2, 3]], ASPHALT)

    from scipy.spatial import cKDTree

    streets = plan.streets()
    full = [_street(nodes, e, 0.0) for e in streets]  # crossing to crossing
    tree = cKDTree(np.concatenate([p.points[:, :2] for p in full] + [centre.points[::5, :2]]))
    _pavements(b, nodes, streets)
    driven = set(plan.edges)
    for e in plan.edges:  # furnished like the urban street, once per street
        path = _street(nodes, e, FACADE)
        for side in (-1.0, 1.0):
            _buildings(b, rng, path, tree, side)
            poles = _poles(b, rng, path, side)
            _trees(b, rng, path, tree, side, poles)
            _parked_cars(b, day, path, side)
        _backdrop(b, rng, path, tree, ends=False)
    for e in streets:
        if e not in driven:
            _plain_fronts(b, rng, _street(nodes, e, FACADE), tree)

    return Scene(
        "town", b.build(), plan.lane, 1.73, LEAD_IN, LEAD_IN + drive, "hdl64e", 10.0, follow_pitch=False,
        ego_boxes=EGO_CAR,
    )


def _pavements(b: MeshBuilder, nodes: np.ndarray, streets: list) -> None:
    """Curbs, sidewalks and lane paint of every street, ending at the crossings, and the sidewalk
    across the mouth of a crossing where the grid has no street (its border)."""
    for e in streets:
        path = _street(nodes, e, ROAD_HALF)
        ends = np.array([0.0, path.length])
        c, n = path.position(ends), path.lateral(ends)  # straight: two sections are enough
        t = path.tangent(ends[:1])[0]
        yaw = math.atan2(t[1], t[0])
        for side in (-1.0, 1.0):
            a, z = side * ROAD_HALF, side * (ROAD_HALF + SIDEWALK)
            b.sweep(c, n, np.array([[a, 0.0], [a, CURB_H], [z, CURB_H], [z, 0.0]]), CONCRETE)
            m = side * 3.5
            b.sweep(c, n, np.array([[m - 0.075, 0.005], [m + 0.075, 0.005]]), PAINT)
            # Close the sidewalk's ends (its curb on the cross street).
            cap = c + side * (ROAD_HALF + SIDEWALK / 2) * n
            cap[:, 2] = CURB_H / 2
            b.boxes(cap, np.array([0.1, SIDEWALK, CURB_H]), yaw, CONCRETE)
        _centre_dashes(b, path)
    width = 2 * (ROAD_HALF + SIDEWALK)
    for i in range(GRID):
        for j in range(GRID):
            for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                if 0 <= i + dx < GRID and 0 <= j + dy < GRID:
                    continue
                centre = np.array([*nodes[i, j], CURB_H / 2])
                centre[:2] += (ROAD_HALF + SIDEWALK / 2) * np.array([dx, dy])
                size = [SIDEWALK, width, CURB_H] if dx else [width, SIDEWALK, CURB_H]
                b.boxes(centre, np.array(size), 0.0, CONCRETE)


def _plain_fronts(b: MeshBuilder, rng: np.random.Generator, path: Path, tree) -> None:
    """Windowless blocks on the facade line of a street the route never drives (seen only down
    its length from a crossing, or through gaps): 12 triangles a building."""
    centres, sizes, yaws, mats = [], [], [], []
    t = path.tangent(np.array([0.0]))[0]
    yaw = math.atan2(t[1], t[0])
    fwd, left = t[:2], np.array([-t[1], t[0]])
    for side in (-1.0, 1.0):
        s = 0.0
        while s < path.length:
            width = rng.uniform(10.0, 30.0)
            sc, s = s + width / 2, s + width + (rng.uniform(5.0, 15.0) if rng.random() < 0.2 else 0.0)
            depth, height = rng.uniform(10.0, 16.0), rng.uniform(6.0, 22.0)
            out = side * (FACADE + rng.uniform(0.0, 3.0) + depth / 2)
            if sc > path.length:
                break
            c = path.position(np.array([sc]))[0, :2] + out * left
            u, v = np.meshgrid(np.linspace(-0.5, 0.5, 7), np.linspace(-0.5, 0.5, 7))
            ring = c + u.reshape(-1, 1) * width * fwd + v.reshape(-1, 1) * depth * left
            if tree.query(ring)[0].min() < FACADE - 0.1:
                continue
            centres.append([c[0], c[1], height / 2])
            sizes.append([width, depth, height])
            yaws.append(yaw)
            mats.append([rng.uniform(0.25, 0.6), 0.0])
    b.boxes(np.array(centres), np.array(sizes), np.array(yaws), np.array(mats))

