"""A small ray-cast street scene with known poses, for the task-metric tests and benchmark.

Kept independent of the ``sim`` plugin so the task metrics are tested on their own: a ground
plane, two facades with recesses, parked boxes and poles (so that ICP is constrained along the
street too), scanned by a preset sensor along a gently curving path.
"""

from __future__ import annotations

import numpy as np

from lwbench import Dataset, Frame, SensorModel, get_sensor, import_open3d

o3d = import_open3d()

# A small 32-beam sensor (28,800 rays) with a street-sized range, so the fast tests stay fast.
TEST32 = SensorModel("test32", tuple(np.linspace(-25.0, 12.0, 32)), 0.4, 0.5, 60.0, 10.0)


def _box(size: tuple[float, float, float], center: tuple[float, float, float]) -> o3d.t.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(np.asarray(center) - np.asarray(size) / 2)
    return o3d.t.geometry.TriangleMesh.from_legacy(m)


def street_scene(length: float = 120.0, seed: int = 0) -> o3d.t.geometry.RaycastingScene:
    rng = np.random.default_rng(seed)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(_box((length + 60, 60, 0.2), (length / 2, 0, -0.1)))  # ground, top at z=0
    for side in (-1, 1):
        x = -30.0
        while x < length + 30:  # facades: blocks of varying depth and height
            w = rng.uniform(6, 14)
            depth = rng.uniform(0, 2.5)
            scene.add_triangles(_box((w, 4, rng.uniform(6, 15)), (x + w / 2, side * (9 + depth + 2), 5)))
            x += w
        for px in np.arange(-20, length + 20, 9.0) + rng.uniform(-2, 2, 1):  # poles
            scene.add_triangles(_box((0.3, 0.3, 5), (px, side * 6.5, 2.5)))
        for cx in rng.uniform(-10, length + 10, int(length / 12)):  # parked cars
            scene.add_triangles(_box((4.2, 1.8, 1.5), (cx, side * rng.uniform(3.5, 5), 0.75)))
    return scene


def street_poses(n: int, step: float = 1.0, sensor_height: float = 1.8) -> np.ndarray:
    """Sensor->world poses along x with a slow lateral weave and matching yaw."""
    poses = np.tile(np.eye(4), (n, 1, 1))
    s = np.arange(n) * step
    y = 1.0 * np.sin(s / 15.0)
    yaw = np.arctan2(np.gradient(y), np.full(n, step)) if n > 1 else np.zeros(n)
    c, si = np.cos(yaw), np.sin(yaw)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -si, si, c
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = s, y, sensor_height
    return poses


def scan(
    scene: o3d.t.geometry.RaycastingScene,
    sensor: SensorModel,
    pose: np.ndarray,
    noise: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Ray-cast one sweep; returns float32 points in the sensor frame."""
    d = sensor.ray_directions().reshape(-1, 3)
    dw = (pose[:3, :3] @ d.T).T
    rays = np.concatenate([np.broadcast_to(pose[:3, 3], dw.shape), dw], axis=1).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
    ok = np.isfinite(t) & (t >= sensor.min_range) & (t <= sensor.max_range)
    r = t[ok] + rng.normal(0, noise, ok.sum()) if noise > 0 else t[ok]
    return (d[ok] * r[:, None]).astype(np.float32)


class StreetDataset(Dataset):
    """In-memory frames of :func:`street_scene`; frames are cast once at construction."""

    name = "test-street"

    def __init__(
        self, n: int = 8, sensor: str = "test32", step: float = 1.0, noise: float = 0.01, seed: int = 0
    ) -> None:
        super().__init__()
        self.sensor = TEST32 if sensor == "test32" else get_sensor(sensor)
        self.poses = street_poses(n, step)
        scene = street_scene(length=n * step + 10, seed=seed)
        rng = np.random.default_rng(seed)
        self._points = [scan(scene, self.sensor, p, noise, rng) for p in self.poses]

    def __len__(self) -> int:
        return len(self._points)

    def frame(self, index: int) -> Frame:
        return Frame(
            self._points[index], self.sensor, index=index, timestamp=0.1 * index, pose=self.poses[index]
        )

    @property
    def has_poses(self) -> bool:
        return True

    def identity(self) -> str:
        return f"test-street:{id(self)}"
