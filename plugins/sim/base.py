"""What every procedural scene is made of: the :class:`Scene` record and shared noise helpers."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .mesh import Mesh
from .trajectory import Path


@dataclass(frozen=True)
class Scene:
    """A world to scan: ``mesh``, the driven ``path`` (on the ground), the sensor's height above
    it, where sequences start by default (``s_start``) and the last driveable point (``s_end``),
    both in metres along the path, and the scene's natural sensor and speed."""

    name: str
    mesh: Mesh
    path: Path
    sensor_height: float
    s_start: float
    s_end: float
    sensor: str
    speed: float
    follow_pitch: bool = True
    # Boxes ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` in the sensor frame that the vehicle
    # itself occupies: rays into them never reach the scene (roof, hood and trunk under a
    # car-mounted LiDAR hide part of its lowest beams, as in every KITTI scan).
    ego_boxes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()


def smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma: tuple[float, float],
                  wrap_second: bool) -> np.ndarray:
    """Gaussian-filtered white noise with unit standard deviation (a cheap 2-D value noise)."""
    mode = ("nearest", "wrap" if wrap_second else "nearest")
    from scipy.ndimage import gaussian_filter  # here: building a scene is rare, discovery is not

    field = gaussian_filter(rng.standard_normal(shape), sigma, mode=mode)
    return field / max(float(field.std()), 1e-12)


def sines(
    rng: np.random.Generator, s: np.ndarray, amps: list[float], wavelengths: list[tuple[float, float]]
) -> np.ndarray:
    """A sum of sinusoids with random wavelengths (within bounds) and phases."""
    out = np.zeros_like(s)
    for a, (lo, hi) in zip(amps, wavelengths, strict=True):
        lam = rng.uniform(lo, hi)
        out += a * np.sin(2 * math.pi * s / lam + rng.uniform(0, 2 * math.pi))
    return out


def per_quad(mat: np.ndarray) -> np.ndarray:
    """Per-quad material ``(S-1, K, 2)`` -> per-triangle, in :meth:`MeshBuilder.sweep`'s order."""
    flat = mat.reshape(-1, 2)
    return np.concatenate([flat, flat])
