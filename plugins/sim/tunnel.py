"""The VSGP paper's simulated mine: a winding drift entered through a portal in a rock face."""

from __future__ import annotations

import math

import numpy as np

from .base import Scene, per_quad, sines, smooth_noise
from .mesh import Material, MeshBuilder
from .trajectory import Path

ROCK = Material(0.35)
ROCK_FLOOR = Material(0.25)


def _tunnel_profile(width: np.ndarray, height: np.ndarray, n_floor: int = 7, n_wall: int = 4,
                    n_arch: int = 15) -> tuple[np.ndarray, np.ndarray]:
    """Horseshoe cross-sections ``(S, K, 2)`` (lateral, up) and the per-vertex floor mask.

    Floor from right to left, left wall up, an elliptical arch over, right wall down: the shape of
    a drill-and-blast mine drift.
    """
    half = width[:, None] / 2
    wall_h = 0.55 * height[:, None]
    f = np.linspace(-1, 1, n_floor)[None, :-1]
    floor = np.stack(np.broadcast_arrays(half * f, 0 * f), -1)
    u = np.linspace(0, 1, n_wall)[None, :-1]
    left = np.stack(np.broadcast_arrays(half + 0 * u, wall_h * u), -1)
    phi = np.linspace(0, math.pi, n_arch)[None, :-1]
    arch = np.stack([half * np.cos(phi), wall_h + (height[:, None] - wall_h) * np.sin(phi)], -1)
    right = np.stack(np.broadcast_arrays(-half + 0 * u, wall_h * (1 - u)), -1)
    profile = np.concatenate([floor, left, arch, right], axis=1)
    is_floor = np.zeros(profile.shape[1], dtype=bool)
    is_floor[: n_floor - 1] = True
    return profile, is_floor


def build_tunnel(
    rng: np.random.Generator, length: float = 135.0, approach: float = 6.0, day: np.random.Generator | None = None
) -> Scene:
    """A winding mine drift entered from outside through a portal in a rock face.

    The path starts ``approach`` metres in front of the portal on open ground (few returns,
    like the VSGP paper's tunnel entrance, Fig. 4) and runs ``length`` metres into the drift.
    Heading, floor elevation, width (3.7-6.3 m) and height (3.2-4.8 m) vary smoothly; the drift
    opens into three chambers up to ~12 m wide and ~8 m high; walls and roof are rough at 1.5 m
    and 0.4 m scales, the floor gently uneven; boulders lie along the walls; the far end is
    closed. The paper's simulated mine (cpr_inspection) is ~135 m long, in a ~30 x 65 m area,
    with varying width, height and ground elevation.
    """
    margin = 3.0
    total = approach + length + margin
    ds_path = 0.05
    s = np.arange(0.0, total + ds_path, ds_path)
    inside = np.maximum(s - approach, 0.0)  # the path is straight and level up to the portal
    # Heading: sinusoids whose curvature stays below ~1/12 m^-1 (a drift a robot can follow).
    heading = sines(rng, inside, [0.55, 0.35, 0.12], [(55, 90), (28, 45), (14, 20)])
    heading += rng.uniform(-math.pi, math.pi) - heading[0]
    z = sines(rng, inside, [0.9, 0.3], [(60, 100), (20, 35)])
    xy = np.cumsum(np.stack([np.cos(heading), np.sin(heading)], 1) * ds_path, axis=0)
    path = Path(np.column_stack([xy - xy[0], z - z[0]]))

    ds = 0.25
    s_ring = np.arange(approach, path.length + 1e-9, ds)
    centres = path.position(s_ring)
    lateral = path.lateral(s_ring)
    width = 5.0 + sines(rng, s_ring, [1.0, 0.3], [(25, 45), (8, 14)])
    height = 4.0 + sines(rng, s_ring, [0.6, 0.2], [(30, 50), (9, 15)])
    # A few chambers (stopes, junction caverns) where the drift opens up to ~2x its size.
    for centre in approach + rng.uniform(0.15, 0.85, 3) * length:
        bump = np.exp(-0.5 * ((s_ring - centre) / rng.uniform(3.0, 6.0)) ** 2)
        width += rng.uniform(4.0, 7.0) * bump
        height += rng.uniform(2.0, 4.0) * bump
    profile, is_floor = _tunnel_profile(width, height)
    # Outward normal of each profile vertex in the (lateral, up) plane, from its neighbours.
    tang = np.roll(profile, -1, axis=1) - np.roll(profile, 1, axis=1)
    normal2 = np.stack([tang[..., 1], -tang[..., 0]], -1)
    normal2 /= np.linalg.norm(normal2, axis=-1, keepdims=True)
    centroid = profile.mean(axis=1, keepdims=True)
    flip = np.sum(normal2 * (profile - centroid), axis=-1, keepdims=True) < 0
    normal2 = np.where(flip, -normal2, normal2)
    shape = profile.shape[:2]
    rough = (
        0.20 * smooth_noise(rng, shape, (6.0, 2.0), True)
        + 0.06 * smooth_noise(rng, shape, (1.5, 0.8), True)
        + 0.015 * rng.standard_normal(shape)
    )
    rough[:, is_floor] *= 0.25  # the floor is driveable: uneven, not jagged
    rough[:2] = rough[-2:] = 0.0  # clean rims where the portal face and the end wall attach
    up = np.array([0.0, 0.0, 1.0])
    offsets = rough[..., None] * (normal2[..., :1] * lateral[:, None, :] + normal2[..., 1:] * up)
    b = MeshBuilder()
    mats = np.where(is_floor[None, :, None], [ROCK_FLOOR.reflectivity, 0.0], [ROCK.reflectivity, 0.0])
    mat_tri = np.broadcast_to(mats, (len(s_ring) - 1, shape[1], 2))
    b.sweep(centres, lateral, profile, per_quad(mat_tri), closed=True, offsets=offsets)
    end_ring = centres[-1] + profile[-1, :, :1] * lateral[-1] + profile[-1, :, 1:] * up
    b.polygon_fan(end_ring, ROCK)
    _portal(b, rng, centres[0], path.tangent(approach), lateral[0],
            centres[0] + profile[0, :, :1] * lateral[0] + profile[0, :, 1:] * up)
    # Boulders along the walls, partly sunk into the floor.
    n_rocks = int(length / 4)
    s_rock = rng.uniform(approach + margin, path.length - margin, n_rocks)
    side = rng.choice([-1.0, 1.0], n_rocks)
    radius = rng.uniform(0.2, 0.55, n_rocks)
    w_at = np.interp(s_rock, s_ring, width)
    lat = side * (w_at / 2 - radius * 0.6)
    pos = path.position(s_rock) + lat[:, None] * path.lateral(s_rock)
    b.blobs(pos, radius, ROCK, rng, roughness=0.3, subdivisions=1, squash=0.7)
    # Sequences start 10 m into the drift by default (the portal then behind, out of range);
    # start=0 drives in from outside.
    return Scene("tunnel", b.build(), path, 0.5, approach + 10.0, approach + length, "vlp16", 1.0)


def _portal(b: MeshBuilder, rng: np.random.Generator, floor_centre: np.ndarray, forward: np.ndarray,
            lateral: np.ndarray, rim: np.ndarray) -> None:
    """The outside at the tunnel mouth: a rough rock face around the portal ``rim`` and open,
    slightly uneven ground with scattered boulders in front of it (never behind the face, where
    it would cut through the drift)."""
    up = np.array([0.0, 0.0, 1.0])
    mid = rim.mean(axis=0)
    scales = np.array([1.0, 1.3, 1.8, 2.8, 4.5, 8.0])
    loops = mid + (rim - mid)[None] * scales[:, None, None]
    bulge = rng.normal(0.0, 0.25, loops.shape[:2]) * (scales[:, None] > 1)
    loops = loops + (bulge - 0.4 * (scales[:, None] - 1))[..., None] * forward  # face leans back
    b.loft(loops, ROCK, closed=True)
    nx, ny = 41, 61  # 1 m cells, 40 m deep, 60 m wide, in front of the face
    gx, gy = np.meshgrid(np.linspace(-40.0, 0.0, nx), np.linspace(-30.0, 30.0, ny), indexing="ij")
    gz = 0.03 * rng.standard_normal(gx.shape) + 0.15 * smooth_noise(rng, gx.shape, (3.0, 3.0), False)
    gz[-1] = 0.0
    verts = floor_centre + gx[..., None] * forward + gy[..., None] * lateral + gz[..., None] * up
    b.loft(verts, ROCK_FLOOR)
    n = 14
    along = rng.uniform(-35.0, -2.0, n)
    across = rng.choice([-1.0, 1.0], n) * rng.uniform(2.5, 25.0, n)
    pos = floor_centre + along[:, None] * forward + across[:, None] * lateral
    b.blobs(pos, rng.uniform(0.3, 1.2, n), ROCK, rng, roughness=0.3, subdivisions=1, squash=0.6)
