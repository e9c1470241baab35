"""Analytic tunnel scans for VSGP's tests, benchmarks and measurements.

The built-in ``sim`` dataset lives in another plugin, and plugins must not import each other, so
VSGP carries its own small scene: a ray-cast elliptic tunnel (optionally with a flat floor)
around a VLP-16-like sensor. Every ray is intersected in closed form, so a 57,600-ray scan costs
a few milliseconds and is exactly reproducible from its seed.
"""

from __future__ import annotations

import numpy as np

from lwbench import Frame, SensorModel, get_sensor

__all__ = ["tunnel_ranges", "tunnel_frame", "cylinder_frame"]


def _ellipse_hit(d: np.ndarray, origin: np.ndarray, a: float, b: float) -> np.ndarray:
    """Distance along each unit ray ``d`` from ``origin`` (inside) to ``y^2/a^2 + z^2/b^2 = 1``."""
    dy, dz = d[..., 1], d[..., 2]
    oy, oz = origin[1], origin[2]
    qa = dy**2 / a**2 + dz**2 / b**2
    qb = 2 * (oy * dy / a**2 + oz * dz / b**2)
    qc = oy**2 / a**2 + oz**2 / b**2 - 1.0  # < 0 inside
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-qb + np.sqrt(np.maximum(qb**2 - 4 * qa * qc, 0.0))) / (2 * qa)
    return np.where(qa > 1e-12, t, np.inf)


def tunnel_ranges(
    sensor: SensorModel,
    *,
    seed: int = 0,
    half_width: float = 2.5,
    half_height: float = 2.2,
    floor: bool = True,
    roughness: float = 0.04,
    noise: float = 0.01,
    dropout: float = 0.01,
) -> np.ndarray:
    """Range image ``(n_beams, n_azimuth)`` of an elliptic tunnel; 0 = no return.

    The tunnel runs along a random heading; the sensor sits off-centre; the wall's radius is
    modulated by a few seeded sinusoids in direction space (rock roughness, relative amplitude
    ``roughness``), and each range gets Gaussian noise ``noise`` (m) and random dropouts.
    Returns beyond the sensor's max range are zeros, like a real sensor's.
    """
    rng = np.random.default_rng(seed)
    a = half_width * rng.uniform(0.85, 1.15)
    b = half_height * rng.uniform(0.85, 1.15)
    heading = rng.uniform(-np.pi, np.pi)
    origin = np.array([0.0, rng.uniform(-0.3, 0.3) * a, rng.uniform(-0.2, 0.1) * b])
    dirs = sensor.ray_directions()  # (B, A, 3), sensor frame
    c, s = np.cos(heading), np.sin(heading)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # sensor -> tunnel frame
    d = dirs @ rot.T
    t = _ellipse_hit(d, origin, a, b)
    if floor:
        floor_z = -0.8 * b
        with np.errstate(divide="ignore", invalid="ignore"):
            tf = np.where(d[..., 2] < -1e-6, (floor_z - origin[2]) / d[..., 2], np.inf)
        t = np.minimum(t, tf)
    az = np.arctan2(d[..., 1], d[..., 0])
    el = np.arcsin(np.clip(d[..., 2], -1, 1))
    bump = np.zeros_like(t)
    for _ in range(6):
        ka, ke = rng.integers(1, 9), rng.uniform(0, 12)
        bump += np.sin(ka * az + ke * el + rng.uniform(0, 2 * np.pi)) / 6
    t = t * (1 + roughness * bump) + rng.normal(0.0, noise, t.shape)
    t[(t < sensor.min_range) | (t > sensor.max_range) | ~np.isfinite(t)] = 0.0
    t[rng.random(t.shape) < dropout] = 0.0
    return t.astype(np.float32)


def tunnel_frame(seed: int = 0, sensor: SensorModel | None = None, **kwargs: float) -> Frame:
    """A :class:`Frame` of :func:`tunnel_ranges` (VLP-16 at 10 m unless a sensor is given)."""
    sensor = sensor or get_sensor("vlp16")
    ranges = tunnel_ranges(sensor, seed=seed, **kwargs)
    return Frame(sensor.unproject(ranges), sensor, index=seed, pose=np.eye(4))


def cylinder_frame(radius: float = 4.0, sensor: SensorModel | None = None, half: bool = False) -> Frame:
    """A noiseless vertical cylinder wall of ``radius`` around the sensor (smooth surface).

    ``half=True`` keeps only the azimuths in ``[0, pi)``: the other half of the scan is free
    space, which the decoder's variance filter must recognise.
    """
    sensor = sensor or get_sensor("vlp16")
    el = sensor.elevations_rad[:, None]
    az = sensor.azimuths_rad()[None, :]
    ranges = np.broadcast_to(radius / np.cos(el), (sensor.n_beams, sensor.n_azimuth)).copy()
    if half:
        ranges[:, (az[0] < 0)] = 0.0
    ranges[ranges > sensor.max_range] = 0.0
    return Frame(sensor.unproject(ranges.astype(np.float32)), sensor, pose=np.eye(4))
