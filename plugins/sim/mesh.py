"""Triangle soups with per-triangle materials, built from vectorized primitives.

A scene is one big triangle array: Open3D's ray caster returns the index of the triangle each
ray hits, so per-triangle arrays (reflectivity, extra dropout) give every return its material
without a second lookup structure. Primitives are generated in batches (all the boxes of a
street at once) because a Python loop per window would make scene building the slow part.
Winding order is irrelevant: intensity uses ``|cos|`` of the incidence angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Material:
    """How a surface returns a laser pulse.

    ``reflectivity`` scales intensity (0..1); ``dropout`` is the extra probability that a ray
    hitting it returns nothing (glass transmits, foliage is porous).
    """

    reflectivity: float
    dropout: float = 0.0


@dataclass(frozen=True)
class Mesh:
    vertices: np.ndarray  # (V, 3) float32, world frame
    triangles: np.ndarray  # (T, 3) int32
    reflectivity: np.ndarray  # (T,) float32
    dropout: np.ndarray  # (T,) float32

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)


# Unit box corners (centred at the origin, side 1) and its 12 triangles.
_BOX_CORNERS = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float64
)
_BOX_TRIS = np.array(
    [
        [0, 1, 3], [0, 3, 2],  # x-
        [4, 6, 7], [4, 7, 5],  # x+
        [0, 4, 5], [0, 5, 1],  # y-
        [2, 3, 7], [2, 7, 6],  # y+
        [0, 2, 6], [0, 6, 4],  # z-
        [1, 5, 7], [1, 7, 3],  # z+
    ],
    dtype=np.int64,
)


def _yaw_matrices(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    r = np.zeros((len(yaw), 3, 3))
    r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1], r[:, 2, 2] = c, -s, s, c, 1.0
    return r


def unit_sphere(subdivisions: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """An icosphere (vertices on the unit sphere, triangles), for tree crowns and shrubs."""
    t = (1 + 5**0.5) / 2
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )
    for _ in range(subdivisions):
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        pairs = [np.stack([a, b], 1), np.stack([b, c], 1), np.stack([c, a], 1)]
        edges = np.sort(np.concatenate(pairs), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        mids = len(v) + np.arange(len(uniq))
        v = np.vstack([v, (v[uniq[:, 0]] + v[uniq[:, 1]]) / 2])
        ab, bc, ca = (mids[inv[i * len(f):(i + 1) * len(f)]] for i in range(3))
        f = np.concatenate([np.stack(x, 1) for x in ([a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca])])
    return v / np.linalg.norm(v, axis=1, keepdims=True), f


class MeshBuilder:
    """Accumulates primitives; :meth:`build` concatenates them into one :class:`Mesh`."""

    def __init__(self) -> None:
        self._verts: list[np.ndarray] = []
        self._tris: list[np.ndarray] = []
        self._refl: list[np.ndarray] = []
        self._drop: list[np.ndarray] = []
        self._n = 0

    def add(self, vertices: np.ndarray, triangles: np.ndarray, material: Material | np.ndarray) -> None:
        """Add a triangle soup; ``material`` is one :class:`Material` or ``(T, 2)`` per triangle."""
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if isinstance(material, Material):
            mat = np.tile([material.reflectivity, material.dropout], (len(triangles), 1))
        else:
            mat = np.asarray(material, dtype=np.float64).reshape(len(triangles), 2)
        self._verts.append(vertices)
        self._tris.append(triangles + self._n)
        self._refl.append(mat[:, 0])
        self._drop.append(mat[:, 1])
        self._n += len(vertices)

    def boxes(
        self, centers: np.ndarray, sizes: np.ndarray, yaws: np.ndarray | float,
        material: Material | np.ndarray,
    ) -> None:
        """Oriented boxes: ``centers`` and ``sizes`` ``(B, 3)``, rotated by ``yaws`` about z;
        ``material`` is one :class:`Material` or ``(B, 2)`` (reflectivity, dropout) per box."""
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        if len(centers) == 0:
            return
        sizes = np.broadcast_to(np.asarray(sizes, dtype=np.float64), centers.shape)
        yaws = np.broadcast_to(np.asarray(yaws, dtype=np.float64), (len(centers),))
        local = _BOX_CORNERS[None] * sizes[:, None, :]
        world = np.einsum("bij,bkj->bki", _yaw_matrices(yaws), local) + centers[:, None, :]
        tris = _BOX_TRIS[None] + 8 * np.arange(len(centers))[:, None, None]
        if not isinstance(material, Material):
            per_box = np.asarray(material, dtype=np.float64).reshape(-1, 2)
            material = np.repeat(per_box, len(_BOX_TRIS), axis=0)
        self.add(world.reshape(-1, 3), tris.reshape(-1, 3), material)

    def cylinders(
        self, bases: np.ndarray, radii: np.ndarray | float, heights: np.ndarray | float,
        material: Material, segments: int = 8,
    ) -> None:
        """Vertical closed cylinders (poles, trunks) standing on ``bases`` ``(B, 3)``."""
        bases = np.asarray(bases, dtype=np.float64).reshape(-1, 3)
        if len(bases) == 0:
            return
        b = len(bases)
        radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (b,))
        heights = np.broadcast_to(np.asarray(heights, dtype=np.float64), (b,))
        a = 2 * np.pi * np.arange(segments) / segments
        ring = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)  # (S, 3)
        bottom = bases[:, None, :] + radii[:, None, None] * ring[None]
        top = bottom + np.stack([np.zeros(b), np.zeros(b), heights], 1)[:, None, :]
        caps = np.stack([bases, bases + np.stack([np.zeros(b), np.zeros(b), heights], 1)], 1)
        verts = np.concatenate([bottom, top, caps], axis=1)  # (B, 2S+2, 3)
        i = np.arange(segments)
        j = (i + 1) % segments
        side = np.concatenate(
            [np.stack([i, j, segments + j], 1), np.stack([i, segments + j, segments + i], 1)]
        )
        cap_b = np.stack([np.full(segments, 2 * segments), j, i], 1)
        cap_t = np.stack([np.full(segments, 2 * segments + 1), segments + i, segments + j], 1)
        tri = np.concatenate([side, cap_b, cap_t])
        n_v = verts.shape[1]
        tris = tri[None] + n_v * np.arange(b)[:, None, None]
        self.add(verts.reshape(-1, 3), tris.reshape(-1, 3), material)

    def blobs(
        self, centers: np.ndarray, radii: np.ndarray, material: Material, rng: np.random.Generator,
        roughness: float = 0.2, subdivisions: int = 2, squash: float = 1.0,
    ) -> None:
        """Irregular spheres (tree crowns, bushes): an icosphere with random radial bumps."""
        centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
        if len(centers) == 0:
            return
        unit, faces = unit_sphere(subdivisions)
        b = len(centers)
        bumps = 1.0 + roughness * (2 * rng.random((b, len(unit))) - 1)
        scale = np.asarray(radii, dtype=np.float64).reshape(b, 1, 1) * bumps[..., None]
        verts = unit[None] * scale * np.array([1.0, 1.0, squash]) + centers[:, None, :]
        tris = faces[None] + len(unit) * np.arange(b)[:, None, None]
        self.add(verts.reshape(-1, 3), tris.reshape(-1, 3), material)

    def sweep(
        self, centres: np.ndarray, lateral: np.ndarray, profile: np.ndarray, material: Material | np.ndarray,
        closed: bool = False, offsets: np.ndarray | None = None,
    ) -> None:
        """Sweep a 2-D cross-section along a centreline (tunnels, curbs, sidewalks).

        ``profile`` is ``(K, 2)`` (lateral, up) in metres, or ``(S, K, 2)`` when it varies along
        the path; ``lateral`` the horizontal unit normal at each of the ``S`` centres;
        ``offsets`` ``(S, K, 3)`` optional per-vertex displacement (wall roughness). ``closed``
        joins the last profile vertex to the first (a tube).
        """
        centres = np.asarray(centres, dtype=np.float64)
        s = len(centres)
        prof = np.broadcast_to(np.asarray(profile, dtype=np.float64), (s, *np.shape(profile)[-2:]))
        up = np.array([0.0, 0.0, 1.0])
        verts = centres[:, None, :] + prof[..., :1] * lateral[:, None, :] + prof[..., 1:] * up
        if offsets is not None:
            verts = verts + offsets
        self.loft(verts, material, closed)

    def loft(self, loops: np.ndarray, material: Material | np.ndarray, closed: bool = False) -> None:
        """Skin consecutive vertex loops ``(L, K, 3)`` with quads (two triangles each); the
        triangle order is all first halves, then all second halves."""
        s, k = loops.shape[:2]
        ii, kk = np.meshgrid(np.arange(s - 1), np.arange(k if closed else k - 1), indexing="ij")
        a = ii * k + kk
        b = ii * k + (kk + 1) % k
        c = a + k
        d = b + k
        tris = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)]).reshape(-1, 3)
        self.add(loops.reshape(-1, 3), tris, material)

    def polygon_fan(self, ring: np.ndarray, material: Material) -> None:
        """Close a (roughly convex) ring of vertices with a fan around its centroid (tunnel ends)."""
        ring = np.asarray(ring, dtype=np.float64)
        verts = np.vstack([ring, ring.mean(axis=0)])
        n = len(ring)
        i = np.arange(n)
        self.add(verts, np.stack([np.full(n, n), i, (i + 1) % n], 1), material)

    def build(self) -> Mesh:
        if not self._verts:
            raise ValueError("empty scene")
        return Mesh(
            np.concatenate(self._verts).astype(np.float32),
            np.concatenate(self._tris).astype(np.int32),
            np.concatenate(self._refl).astype(np.float32),
            np.concatenate(self._drop).astype(np.float32),
        )
