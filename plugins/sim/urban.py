"""A KITTI-like street: the setting of PocoNet's localization experiments.

An L-shaped street (a straight of ~120 m, a 90-degree corner of 15 m radius, then a second
straight) lined with raised sidewalks and curbs, building facades with floor slabs, pilasters and
recessed glass windows, lamp poles and sign posts, street trees (trunk + porous crown) and parked
cars. A car with an HDL-64E at 1.73 m (KITTI's mounting height) drives 200 m in the right lane at
10 m/s. The vertical structure (poles, trunks, window edges) constrains ICP along the street,
where a corridor of flat facades alone would leave it sliding; it is also what makes some points
matter more than others for PocoNet's observation-count labels.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .base import Scene
from .mesh import Material, MeshBuilder
from .trajectory import Path, waypoint_path

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

ASPHALT = Material(0.4)
PAINT = Material(0.9)
CONCRETE = Material(0.45)
GLASS = Material(0.08, dropout=0.5)  # mostly transmits: the return is often lost
METAL = Material(0.5)
BARK = Material(0.3)
FOLIAGE = Material(0.25, dropout=0.35)  # porous: many pulses go through the gaps
HEDGE = Material(0.3, dropout=0.15)
FENCE = Material(0.45)
CAR_PAINT = Material(0.45)
CAR_GLASS = Material(0.1, dropout=0.4)
TYRE = Material(0.05)

# The recording car around a roof-mounted sensor 1.73 m above the road (KITTI's VW Passat):
# cabin and roof (top 0.35 m below the sensor), then hood and trunk (top ~0.85 m above the
# road). Sized so that ~7,400 of the 131,072 rays are hidden, mostly of the lowest beams ahead
# and behind: KITTI 00 has ~8k points within 5 m where a free sensor would have ~18k.
EGO_CAR = (
    ((-1.0, -0.65, -1.2), (0.2, 0.65, -0.35)),
    ((-1.8, -0.85, -1.45), (2.0, 0.85, -0.9)),
)
ROAD_HALF = 7.0  # curb line: two 3.5 m lanes, parking strips inside them
SIDEWALK = 3.5
CURB_H = 0.15
LANE = -1.75  # the car drives in the right-hand lane (lateral axis points left)


def build_urban(rng: np.random.Generator, drive: float = 200.0, day: np.random.Generator | None = None) -> Scene:
    """The street; ``day`` draws what changes between two drives along it (which parking slots
    are taken, and by what): the static city comes from ``rng`` alone."""
    day = day if day is not None else np.random.default_rng(rng.integers(2**63))
    lead_in = 60.0  # street behind the start, so the first scans see buildings behind the car
    first = rng.uniform(110.0, 130.0)
    turn = rng.choice([-1.0, 1.0])
    waypoints = np.array([[-lead_in, 0.0], [first, 0.0], [first, turn * 160.0]])
    centre = Path(waypoint_path(waypoints, radius=15.0, step=0.1))
    b = MeshBuilder()
    lo = centre.points[:, :2].min(axis=0) - 120
    hi = centre.points[:, :2].max(axis=0) + 120
    ground = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    b.add(ground, [[0, 1, 2], [0, 2, 3]], ASPHALT)

    s_fine = np.arange(0.0, centre.length, 0.5)
    c_fine, n_fine = centre.position(s_fine), centre.lateral(s_fine)
    for side in (-1.0, 1.0):
        a, z = side * ROAD_HALF, side * (ROAD_HALF + SIDEWALK)
        b.sweep(c_fine, n_fine, np.array([[a, 0.0], [a, CURB_H], [z, CURB_H], [z, 0.0]]), CONCRETE)
        # Lane edge line (continuous) between the driving lane and the parking strip.
        e = side * 3.5
        b.sweep(c_fine, n_fine, np.array([[e - 0.075, 0.005], [e + 0.075, 0.005]]), PAINT)
    _centre_dashes(b, centre)
    from scipy.spatial import cKDTree

    tree = cKDTree(centre.points[:, :2])
    for side in (-1.0, 1.0):
        _buildings(b, rng, centre, tree, side)
        poles = _poles(b, rng, centre, side)
        _trees(b, rng, centre, tree, side, poles)
        _parked_cars(b, day, centre, side)

    _backdrop(b, rng, centre, tree)
    lane = centre.points + LANE * centre.lateral(centre.s)
    path = Path(lane)
    return Scene(
        "urban", b.build(), path, 1.73, lead_in, lead_in + drive, "hdl64e", 10.0, follow_pitch=False,
        ego_boxes=EGO_CAR,
    )


def _frames_along(centre: Path, s: np.ndarray, lateral: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ground positions at arc lengths ``s`` and ``lateral`` metres to the left, and the yaw."""
    t = centre.tangent(s)
    pos = centre.position(s) + np.reshape(lateral, (-1, 1)) * centre.lateral(s)
    return pos, np.arctan2(t[:, 1], t[:, 0])


def _centre_dashes(b: MeshBuilder, centre: Path) -> None:
    s = np.arange(2.0, centre.length - 2.0, 9.0)
    pos, yaw = _frames_along(centre, s, 0.0)
    pos[:, 2] = 0.005
    b.boxes(pos, np.array([3.0, 0.15, 0.01]), yaw, PAINT)


def _buildings(b: MeshBuilder, rng: np.random.Generator, centre: Path, tree: cKDTree, side: float) -> None:
    """Lots of random width along one side; each building a box set back 0.3 m behind its facade
    line, with floor slabs and pilasters on the facade line and a glass pane in every bay."""
    facade_line = ROAD_HALF + SIDEWALK + 0.5
    s = 0.0
    body_c, body_s, body_y, body_m = [], [], [], []
    strip_c, strip_s, strip_y, strip_m = [], [], [], []
    pane_c, pane_s, pane_y = [], [], []
    fence_s: list[tuple[float, float]] = []  # stretches of hedge or fence along the facade line
    while s < centre.length:
        width = rng.uniform(8.0, 22.0)
        if rng.random() < 0.25:  # an alley, a side street or an open lot, often fenced
            gap = rng.uniform(5.0, 20.0)
            if rng.random() < 0.6:
                fence_s.append((s, s + gap))
            s += gap
            continue
        setback = rng.uniform(0.0, 3.5)
        if setback > 1.5 and rng.random() < 0.5:  # a front garden behind a hedge
            fence_s.append((s, s + width))
        depth = rng.uniform(10.0, 16.0)
        floors = int(rng.integers(2, 8))
        floor_h = rng.uniform(2.9, 3.4)
        height = floors * floor_h + rng.uniform(0.3, 1.2)
        wall = [rng.uniform(0.25, 0.6), 0.0]
        sc = s + width / 2
        s += width + rng.uniform(0.0, 1.0)
        if sc > centre.length:
            break
        front = facade_line + setback
        pos, yaw = _frames_along(centre, np.array([sc]), side * (front + depth / 2))
        yaw = float(yaw[0])
        fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        left = np.array([-fwd[1], fwd[0], 0.0])
        out = -side * left  # from the building towards the street
        c = pos[0]
        # Reject lots that would reach into the street (the inside of the corner).
        u, v = np.meshgrid(np.linspace(-0.5, 0.5, 9), np.linspace(-0.5, 0.5, 9))
        ring = c[:2] + u.reshape(-1, 1) * width * fwd[:2] + v.reshape(-1, 1) * depth * left[:2]
        if tree.query(ring)[0].min() < facade_line - 0.1:
            continue
        body_c.append(c + np.array([0, 0, height / 2]) - 0.15 * out)
        body_s.append([width, depth - 0.3, height])
        body_y.append(yaw)
        body_m.append(wall)
        face = c + out * (depth / 2)  # the facade line, on the ground
        # Floor slabs across the whole front, 0.3 m deep.
        for k in range(1, floors + 1):
            strip_c.append(face - 0.15 * out + np.array([0, 0, k * floor_h - 0.2]))
            strip_s.append([width, 0.3, 0.4])
            strip_y.append(yaw)
            strip_m.append(wall)
        bays = max(1, int(round(width / rng.uniform(2.6, 3.6))))
        bay = width / bays
        for j in range(bays + 1):
            along = -width / 2 + j * bay
            strip_c.append(face - 0.15 * out + along * fwd + np.array([0, 0, height / 2]))
            strip_s.append([0.5, 0.3, height])
            strip_y.append(yaw)
            strip_m.append(wall)
        # Glass panes in each bay and floor, 5 cm in front of the recessed wall.
        jj, kk = np.meshgrid(np.arange(bays), np.arange(floors), indexing="ij")
        along = -width / 2 + (jj.reshape(-1) + 0.5) * bay
        up = (kk.reshape(-1) + 0.5) * floor_h
        pane_c.append(face[None] - 0.25 * out + along[:, None] * fwd + up[:, None] * np.array([0, 0, 1.0]))
        pane_s.append(np.tile([bay - 1.2, 0.02, floor_h - 1.1], (len(along), 1)))
        pane_y.append(np.full(len(along), yaw))
    _fences(b, rng, centre, tree, side, facade_line, fence_s)
    if body_c:
        b.boxes(np.array(body_c), np.array(body_s), np.array(body_y), np.array(body_m))
        b.boxes(np.array(strip_c), np.array(strip_s), np.array(strip_y), np.array(strip_m))
        b.boxes(np.concatenate(pane_c), np.concatenate(pane_s), np.concatenate(pane_y), GLASS)


def _backdrop(b: MeshBuilder, rng: np.random.Generator, centre: Path, tree: cKDTree, ends: bool = True) -> None:
    """Plain blocks behind the street front (25-45 m out) and, with ``ends``, across both ends of
    the street: a city goes on behind the first row, so rays through alleys and down the street
    still end on something, as the upper beams of a real urban scan mostly do. (The town, whose
    streets end in crossings, passes ``ends=False``; the end walls draw nothing from ``rng``.)"""
    centres, sizes, yaws, mats = [], [], [], []
    for side in (-1.0, 1.0):
        s = 0.0
        while s < centre.length:
            width = rng.uniform(12.0, 30.0)
            sc, s = s + width / 2, s + width + rng.uniform(0.0, 8.0)
            depth, height = rng.uniform(10.0, 20.0), rng.uniform(6.0, 24.0)
            out = side * rng.uniform(25.0, 45.0)
            pos, yaw = _frames_along(centre, np.array([min(sc, centre.length)]), out)
            fwd = np.array([math.cos(yaw[0]), math.sin(yaw[0])])
            left = np.array([-fwd[1], fwd[0]])
            u, v = np.meshgrid(np.linspace(-0.5, 0.5, 7), np.linspace(-0.5, 0.5, 7))
            ring = pos[0, :2] + u.reshape(-1, 1) * width * fwd + v.reshape(-1, 1) * depth * left
            if tree.query(ring)[0].min() < ROAD_HALF + SIDEWALK + 8.0:
                continue
            centres.append(pos[0] + [0.0, 0.0, height / 2])
            sizes.append([width, depth, height])
            yaws.append(yaw[0])
            mats.append([rng.uniform(0.25, 0.6), 0.0])
    for end, sign in ((0.0, -1.0), (centre.length, 1.0)) if ends else ():  # across the street, past each end
        t = centre.tangent(np.array([end]))[0]
        pos = centre.position(np.array([end]))[0] + sign * 12.0 * t
        centres.append(pos + [0.0, 0.0, 10.0])
        sizes.append([8.0, 80.0, 20.0])
        yaws.append(math.atan2(t[1], t[0]))
        mats.append([0.4, 0.0])
    b.boxes(np.array(centres), np.array(sizes), np.array(yaws), np.array(mats))


def _fences(b: MeshBuilder, rng: np.random.Generator, centre: Path, tree: cKDTree, side: float,
            line: float, stretches: list[tuple[float, float]]) -> None:
    """Hedges and fences (0.8-1.8 m) along the facade line, in 2 m pieces so they follow curves."""
    for a, c in stretches:
        s = np.arange(a + 1.0, min(c, centre.length) - 0.5, 2.0)
        if len(s) == 0:
            continue
        pos, yaw = _frames_along(centre, s, side * (line + 0.2))
        clear = tree.query(pos[:, :2])[0] > line - 0.1
        pos, yaw = pos[clear], yaw[clear]
        if len(pos) == 0:
            continue
        height = rng.uniform(0.8, 1.8)
        pos[:, 2] = height / 2
        hedge = rng.random() < 0.5
        size = np.array([2.05, 0.6 if hedge else 0.1, height])
        b.boxes(pos, size, yaw, HEDGE if hedge else FENCE)


def _poles(b: MeshBuilder, rng: np.random.Generator, centre: Path, side: float) -> np.ndarray:
    """Lamp posts (7-8 m, with an arm over the road) and sign posts (2.5 m, with a plate) on the
    sidewalk edge; returns their arc lengths so trees keep clear of them."""
    s = np.cumsum(rng.uniform(15.0, 30.0, int(centre.length / 15) + 1))
    s = s[s < centre.length - 2]
    lamp = rng.random(len(s)) < 0.6
    pos, yaw = _frames_along(centre, s, side * (ROAD_HALF + 0.5))
    pos[:, 2] = CURB_H
    heights = np.where(lamp, rng.uniform(7.0, 8.0, len(s)), 2.6)
    b.cylinders(pos, 0.09, heights, METAL)
    road = -side * np.stack([-np.sin(yaw), np.cos(yaw), np.zeros_like(yaw)], 1)  # towards the road
    arm_c = pos + road * 0.8 + np.stack([0 * yaw, 0 * yaw, heights - 0.15], 1)
    b.boxes(arm_c[lamp], np.array([0.12, 1.6, 0.12]), yaw[lamp], METAL)
    plate_c = pos + np.stack([0 * yaw, 0 * yaw, heights + 0.3], 1)
    b.boxes(plate_c[~lamp], np.array([0.04, 0.7, 0.6]), yaw[~lamp], Material(0.9))
    return s


def _trees(b: MeshBuilder, rng: np.random.Generator, centre: Path, tree: cKDTree, side: float,
           poles: np.ndarray) -> None:
    s = np.cumsum(rng.uniform(6.0, 11.0, int(centre.length / 6) + 1))
    s = s[(s < centre.length - 2) & (rng.random(len(s)) < 0.8)]
    s = s[np.min(np.abs(s[:, None] - poles[None, :]), axis=1) > 3.0] if len(poles) else s
    pos, _ = _frames_along(centre, s, side * (ROAD_HALF + 2.2))
    ok = tree.query(pos[:, :2])[0] > ROAD_HALF + 1.0  # not on the road at the inside of the corner
    pos = pos[ok]
    pos[:, 2] = CURB_H
    n = len(pos)
    trunk_h = rng.uniform(2.5, 4.0, n)
    b.cylinders(pos, rng.uniform(0.12, 0.25, n), trunk_h, BARK, segments=8)
    crown_r = rng.uniform(1.8, 3.2, n)
    crown = pos + np.stack([np.zeros(n), np.zeros(n), trunk_h + 0.7 * crown_r], 1)
    b.blobs(crown, crown_r, FOLIAGE, rng, roughness=0.25, subdivisions=2, squash=0.85)


def _parked_cars(b: MeshBuilder, rng: np.random.Generator, centre: Path, side: float) -> None:
    """Cars in the parking strip, 6 m slots, on the straights only."""
    slots = np.arange(8.0, centre.length - 8.0, 6.0)
    t0, t1 = centre.tangent(slots - 4.0), centre.tangent(slots + 4.0)
    straight = np.einsum("ij,ij->i", t0, t1) > math.cos(math.radians(3))
    slots = slots[straight & (rng.random(len(slots)) < 0.55)]
    n = len(slots)
    if n == 0:
        return
    pos, yaw = _frames_along(centre, slots + rng.uniform(-0.6, 0.6, n), side * rng.uniform(5.4, 5.9, n))
    length = rng.uniform(3.9, 4.8, n)
    fwd = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n)], 1)
    left = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros(n)], 1)
    up = np.array([0.0, 0.0, 1.0])
    b.boxes(pos + 0.7 * up, np.stack([length, np.full(n, 1.8), np.full(n, 0.75)], 1), yaw, CAR_PAINT)
    b.boxes(pos + 1.32 * up - 0.1 * length[:, None] * fwd,
            np.stack([0.52 * length, np.full(n, 1.6), np.full(n, 0.5)], 1), yaw, CAR_GLASS)
    for a in (-0.33, 0.33):
        for c in (-0.8, 0.8):
            wheel = pos + 0.33 * up + a * length[:, None] * fwd + c * left
            b.boxes(wheel, np.array([0.66, 0.22, 0.66]), yaw, TYRE)
