"""Trajectory error math: SE(3) errors, Umeyama alignment, APE and RPE statistics.

The definitions follow evo (Grupp, https://github.com/MichaelGrupp/evo) so that numbers are
comparable with what the SLAM community reports, but the code is written here from the
definitions: evo is GPL-3.0 and is used only as a test oracle (``tests/test_trajectory.py``).

Conventions (evo's):
- a trajectory is an ``(n, 4, 4)`` array of poses (sensor -> world);
- the absolute error pose at ``i`` is ``E_i = est_i^-1 @ ref_i``; its translation part is
  measured on positions, ``|t_est_i - t_ref_i|``;
- the relative error for a pair ``(i, j)`` is ``E = (ref_i^-1 ref_j)^-1 (est_i^-1 est_j)``, pairs
  taken every ``delta`` frames (consecutive, non-overlapping: ``(0, d), (d, 2d), ...``);
- rotation angle = the angle of the rotation's axis-angle vector (``|log R|``);
  ``rotation_part`` = ``|R - I|_F``; ``full_transformation`` = ``|E - I|_F``;
- statistics: rmse, mean, median, std (population, ``ddof=0``), min, max, sse.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "PoseRelation",
    "Sim3",
    "absolute_errors",
    "ape",
    "error_statistics",
    "relative_errors",
    "rotation_angle",
    "rpe",
    "se3_inverse",
    "umeyama",
]

PoseRelation = Literal[
    "translation_part", "rotation_angle_rad", "rotation_angle_deg", "rotation_part", "full_transformation"
]


def _as_poses(poses: np.ndarray) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (4, 4):
        raise ValueError(f"poses must have shape (n, 4, 4), got {p.shape}")
    return p


def se3_inverse(poses: np.ndarray) -> np.ndarray:
    """Inverse of one ``(4,4)`` or many ``(n,4,4)`` rigid transforms, without a general inverse."""
    p = np.asarray(poses, dtype=np.float64)
    rt = np.swapaxes(p[..., :3, :3], -1, -2)
    out = np.zeros_like(p)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, p[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rotation_angle(rotations: np.ndarray, degrees: bool = False) -> np.ndarray:
    """Angle of each rotation matrix ``(..., 3, 3)``, in ``[0, pi]``.

    Computed through scipy's quaternion conversion (which projects a slightly non-orthonormal
    matrix, e.g. a pose read from a text file with 7 digits, onto SO(3)) rather than
    ``arccos((tr R - 1)/2)``, which loses half the digits for small angles.
    """
    r = np.asarray(rotations, dtype=np.float64)
    flat = r.reshape(-1, 3, 3)
    if len(flat) == 0:
        return np.zeros(r.shape[:-2])
    from scipy.spatial.transform import Rotation

    angles = Rotation.from_matrix(flat).magnitude().reshape(r.shape[:-2])
    return np.degrees(angles) if degrees else angles


def _relation_errors(e: np.ndarray, relation: PoseRelation) -> np.ndarray:
    if relation == "translation_part":
        return np.linalg.norm(e[:, :3, 3], axis=1)
    if relation == "rotation_angle_rad":
        return rotation_angle(e[:, :3, :3])
    if relation == "rotation_angle_deg":
        return rotation_angle(e[:, :3, :3], degrees=True)
    if relation == "rotation_part":
        return np.linalg.norm(e[:, :3, :3] - np.eye(3), axis=(1, 2))
    if relation == "full_transformation":
        return np.linalg.norm(e - np.eye(4), axis=(1, 2))
    raise ValueError(f"unknown pose relation {relation!r}")


def absolute_errors(
    ref: np.ndarray, est: np.ndarray, relation: PoseRelation = "translation_part"
) -> np.ndarray:
    """Per-pose APE values (evo's ``APE``): one error per pose pair."""
    ref, est = _as_poses(ref), _as_poses(est)
    if ref.shape != est.shape:
        raise ValueError(f"trajectories differ in length: {len(ref)} vs {len(est)}")
    if relation == "translation_part":
        return np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    return _relation_errors(se3_inverse(est) @ ref, relation)


def relative_errors(
    ref: np.ndarray, est: np.ndarray, relation: PoseRelation = "translation_part", delta: int = 1
) -> np.ndarray:
    """Per-pair RPE values (evo's ``RPE`` with ``delta`` in frames, consecutive pairs)."""
    ref, est = _as_poses(ref), _as_poses(est)
    if ref.shape != est.shape:
        raise ValueError(f"trajectories differ in length: {len(ref)} vs {len(est)}")
    if delta < 1:
        raise ValueError(f"delta must be >= 1 frame, got {delta}")
    ids = np.arange(0, len(ref), delta)
    i, j = ids[:-1], ids[1:]
    ref_rel = se3_inverse(ref[i]) @ ref[j]
    est_rel = se3_inverse(est[i]) @ est[j]
    return _relation_errors(se3_inverse(ref_rel) @ est_rel, relation)


def error_statistics(errors: np.ndarray) -> dict[str, float | None]:
    """rmse, mean, median, std, min, max, sse of an error array; ``None`` for an empty one."""
    e = np.asarray(errors, dtype=np.float64)
    keys = ("rmse", "mean", "median", "std", "min", "max", "sse")
    if e.size == 0:
        return dict.fromkeys(keys)
    sq = e * e
    return {
        "rmse": float(np.sqrt(sq.mean())),
        "mean": float(e.mean()),
        "median": float(np.median(e)),
        "std": float(e.std()),
        "min": float(e.min()),
        "max": float(e.max()),
        "sse": float(sq.sum()),
    }


def ape(
    ref: np.ndarray, est: np.ndarray, relation: PoseRelation = "translation_part"
) -> dict[str, float | None]:
    """APE statistics (no alignment: align first with :func:`umeyama` when the frames differ)."""
    return error_statistics(absolute_errors(ref, est, relation))


def rpe(
    ref: np.ndarray, est: np.ndarray, relation: PoseRelation = "translation_part", delta: int = 1
) -> dict[str, float | None]:
    """RPE statistics over consecutive pairs ``delta`` frames apart."""
    return error_statistics(relative_errors(ref, est, relation, delta))


@dataclass(frozen=True)
class Sim3:
    """``x -> scale * rotation @ x + translation``."""

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def apply_poses(self, poses: np.ndarray) -> np.ndarray:
        """Move a trajectory: scale the positions, then apply the rigid part (as evo's ``align``)."""
        p = _as_poses(poses).copy()
        p[:, :3, 3] *= self.scale
        rigid = np.eye(4)
        rigid[:3, :3] = self.rotation
        rigid[:3, 3] = self.translation
        return rigid @ p


def umeyama(x: np.ndarray, y: np.ndarray, with_scale: bool = False) -> Sim3:
    """Least-squares Sim(3) (or SE(3)) mapping points ``x`` onto ``y`` (Umeyama, PAMI 1991).

    ``x``, ``y``: ``(n, 3)`` corresponding points. Raises ``ValueError`` when the points are
    degenerate (fewer than two non-zero singular values of the cross-covariance: e.g. all on
    one point), since the rotation is then not determined.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2:
        raise ValueError(f"need two (n, m) arrays of the same shape, got {x.shape} and {y.shape}")
    n, m = x.shape
    mx, my = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - mx, y - my
    var_x = float((xc * xc).sum()) / n
    cov = yc.T @ xc / n  # eq. 38
    u, d, vt = np.linalg.svd(cov)
    if np.count_nonzero(d > np.finfo(d.dtype).eps) < m - 1:
        raise ValueError("degenerate point sets: Umeyama alignment is not determined")
    s = np.eye(m)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[-1, -1] = -1.0  # keep a proper rotation (no reflection)
    r = u @ s @ vt
    c = float(np.trace(np.diag(d) @ s) / var_x) if with_scale else 1.0
    t = my - c * r @ mx
    return Sim3(rotation=r, translation=t, scale=c)
