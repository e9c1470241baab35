"""Smooth paths and the ground-truth sensor poses along them.

A path is a dense 3-D polyline parametrised by arc length. The vehicle moves along it at a
constant speed, its yaw and pitch follow the tangent (a robot drives forward, climbing with the
floor) and roll is zero, so consecutive poses differ by a small, smooth motion -- what odometry
and the localization metric expect of a real drive.
"""

from __future__ import annotations

import math

import numpy as np


class Path:
    """A dense polyline ``points (N, 3)`` with arc-length interpolation."""

    def __init__(self, points: np.ndarray) -> None:
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
            raise ValueError("a path needs at least two 3-D points")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        keep = np.concatenate([[True], seg > 1e-9])
        self.points = pts[keep]
        self.s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.points, axis=0), axis=1))])

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def position(self, s: np.ndarray | float) -> np.ndarray:
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.length)
        return np.stack([np.interp(s, self.s, self.points[:, k]) for k in range(3)], axis=-1)

    def tangent(self, s: np.ndarray | float, h: float = 0.5) -> np.ndarray:
        """Unit tangent by a central difference over ``h`` metres (smooths polyline kinks)."""
        s = np.asarray(s, dtype=np.float64)
        d = self.position(s + h) - self.position(s - h)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def lateral(self, s: np.ndarray | float) -> np.ndarray:
        """Horizontal unit normal pointing left of the direction of travel."""
        t = self.tangent(s)
        n = np.stack([-t[..., 1], t[..., 0], np.zeros_like(t[..., 0])], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def pose(self, s: float, height: float, follow_pitch: bool = True) -> np.ndarray:
        """4x4 sensor -> world at arc length ``s``, ``height`` above the path; x forward, z up."""
        return self.poses(np.array([s]), height, follow_pitch)[0]

    def poses(self, s: np.ndarray, height: float, follow_pitch: bool = True) -> np.ndarray:
        """Poses ``(len(s), 4, 4)``: yaw (and pitch) follow the tangent, roll is zero."""
        s = np.asarray(s, dtype=np.float64).reshape(-1)
        t = self.tangent(s)
        yaw = np.arctan2(t[:, 1], t[:, 0])
        pitch = -np.arctan2(t[:, 2], np.hypot(t[:, 0], t[:, 1])) if follow_pitch else np.zeros(len(s))
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        out = np.tile(np.eye(4), (len(s), 1, 1))
        # R = Rz(yaw) @ Ry(pitch)
        out[:, 0, 0], out[:, 0, 1], out[:, 0, 2] = cy * cp, -sy, cy * sp
        out[:, 1, 0], out[:, 1, 1], out[:, 1, 2] = sy * cp, cy, sy * sp
        out[:, 2, 0], out[:, 2, 1], out[:, 2, 2] = -sp, 0.0, cp
        out[:, :3, 3] = self.position(s) + np.array([0.0, 0.0, height])
        return out


def waypoint_path(waypoints: np.ndarray, radius: float, step: float = 0.05) -> np.ndarray:
    """A 2-D polyline through ``waypoints`` with every corner rounded by a circular arc of
    ``radius`` (a driveable path: continuous heading), sampled every ``step`` metres; z = 0."""
    w = np.asarray(waypoints, dtype=np.float64)
    pieces: list[np.ndarray] = []
    start = w[0]
    for i in range(1, len(w) - 1):
        a, b, c = w[i - 1], w[i], w[i + 1]
        u = (b - a) / np.linalg.norm(b - a)
        v = (c - b) / np.linalg.norm(c - b)
        turn = math.atan2(u[0] * v[1] - u[1] * v[0], float(u @ v))
        cut = radius * math.tan(abs(turn) / 2)
        p_in, p_out = b - u * cut, b + v * cut
        pieces.append(_line(start, p_in, step))
        left = np.array([-u[1], u[0]]) * math.copysign(1.0, turn)
        centre = p_in + left * radius
        a0 = math.atan2(*(p_in - centre)[::-1])
        n = max(2, int(abs(turn) * radius / step))
        ang = a0 + np.linspace(0, turn, n)
        pieces.append(centre + radius * np.stack([np.cos(ang), np.sin(ang)], 1))
        start = p_out
    pieces.append(_line(start, w[-1], step))
    xy = np.concatenate(pieces)
    return np.column_stack([xy, np.zeros(len(xy))])


def _line(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    n = max(2, int(np.linalg.norm(b - a) / step) + 1)
    return a + np.linspace(0, 1, n)[:, None] * (b - a)
