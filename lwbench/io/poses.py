"""Pose, calibration and time-stamp files: KITTI (3x4 rows, ``calib.txt``'s ``Tr``, ``times.txt``),
TUM and stamped KITTI -- checked (finite, rigid, within the Earth's radius), never trusted."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError

__all__ = ["read_kitti_poses", "read_kitti_calib", "read_pose_file", "read_times"]


_MAX_TRANSLATION_M = 1e8  # more than the Earth's radius (ECEF poses)


def _numbers(path: str | Path, lines: list[list[str]], what: str) -> np.ndarray:
    """Rows of numbers, or a :class:`DataFormatError` naming the first line that is not."""
    try:
        return np.array(lines, dtype=np.float64).reshape(len(lines), -1)
    except ValueError:
        for i, ln in enumerate(lines):
            try:
                [float(v) for v in ln]
            except ValueError:
                text = " ".join(ln)[:80]
                raise DataFormatError(f"{path}: line {i + 1} of the {what} is not numbers: {text!r}") from None
        raise DataFormatError(f"{path}: the {what} is not a table of numbers") from None


def _checked_poses(path: str | Path, poses: np.ndarray) -> np.ndarray:
    """Poses a real trajectory can have: finite, rotations orthonormal (to 1 %, as files print
    them), translations within the Earth's radius. A NaN pose or a zero quaternion would
    otherwise end in a traceback, or in metrics that quietly compare against nonsense."""
    bad = ~np.isfinite(poses).all(axis=(1, 2))
    if bad.any():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(bad)[0]) + 1} holds NaN/inf")
    rot = poses[:, :3, :3]
    err = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(rot)
    worst = np.flatnonzero((err > 1e-2) | (det < 0))
    if len(worst):
        raise DataFormatError(f"{path}: pose {int(worst[0]) + 1} is not rigid (orthonormal rotation, det +1)")
    far = np.abs(poses[:, :3, 3]).max(axis=1) > _MAX_TRANSLATION_M
    if far.any():
        first = int(np.flatnonzero(far)[0]) + 1
        raise DataFormatError(f"{path}: pose {first} lies more than {_MAX_TRANSLATION_M:g} m away")
    return poses


def _rows_to_poses(rows: np.ndarray) -> np.ndarray:
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :4] = rows.reshape(-1, 3, 4)
    return poses


def _pose_lines(path: str | Path) -> list[list[str]]:
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable pose file ({exc})") from None
    lines = [ln.split() for ln in text.splitlines() if ln.strip() and ln.lstrip()[0] != "#"]
    if not lines:
        raise DataFormatError(f"{path}: empty pose file")
    return lines


def read_kitti_poses(path: str | Path) -> np.ndarray:
    """``poses.txt``: one row of 12 numbers (3x4, row-major) per frame -> ``(N, 4, 4)``."""
    lines = _pose_lines(path)
    width = {len(ln) for ln in lines}
    if width != {12}:
        raise DataFormatError(f"{path}: expected 12 numbers per line, got {sorted(width)}")
    return _checked_poses(path, _rows_to_poses(_numbers(path, lines, "poses")))


def read_kitti_calib(path: str | Path) -> np.ndarray | None:
    """The ``Tr`` (velodyne -> camera) transform of a KITTI odometry ``calib.txt``, if present."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable calib.txt ({exc})") from None
    for line in text.splitlines():
        key, _, values = line.partition(":")
        if key.strip() in ("Tr", "Tr_velo_to_cam"):
            row = _numbers(path, [values.split()], "Tr line")
            if row.size != 12:
                raise DataFormatError(f"{path}: Tr holds {row.size} numbers, not 12")
            t = np.eye(4)
            t[:3, :4] = row.reshape(3, 4)
            return _checked_poses(path, t[None])[0]
    return None


def read_times(path: str | Path, n: int | None = None) -> np.ndarray:
    """``times.txt``: one time stamp (s) per line, finite."""
    lines = _pose_lines(path)
    if {len(ln) for ln in lines} != {1}:
        raise DataFormatError(f"{path}: expected one time stamp per line")
    stamps = _numbers(path, lines, "time stamps")[:, 0]
    if not np.isfinite(stamps).all():
        raise DataFormatError(f"{path}: time stamps hold NaN/inf")
    return stamps


def read_pose_file(path: str | Path) -> tuple[list[str] | None, np.ndarray]:
    """A pose file in any of the layouts real datasets use, detected from its columns:

    - 12 numbers: KITTI (3x4 row-major), one line per frame in order;
    - 8 numbers: TUM (``stamp tx ty tz qx qy qz qw``);
    - a key then 12 numbers: stamped KITTI (key = file stem or time stamp);
    - a key then 7 numbers: TUM with a non-numeric stamp.

    Returns the per-line keys (``None`` for plain KITTI) and ``(N, 4, 4)`` poses, checked
    (finite, rigid; a TUM quaternion of zero length is an error, not a traceback).
    """
    from scipy.spatial.transform import Rotation

    lines = _pose_lines(path)
    width = {len(ln) for ln in lines}
    if len(width) != 1:
        raise DataFormatError(f"{path}: lines have different numbers of fields {sorted(width)}")
    (w,) = width
    if w == 12:
        return None, _checked_poses(path, _rows_to_poses(_numbers(path, lines, "poses")))
    if w not in (8, 13):
        raise DataFormatError(f"{path}: {w} fields per line is neither KITTI (12) nor TUM (8)")
    keys = [ln[0] for ln in lines]
    vals = _numbers(path, [ln[1:] for ln in lines], "poses")
    if w == 13:
        return keys, _checked_poses(path, _rows_to_poses(vals))
    if not np.isfinite(vals).all():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(~np.isfinite(vals).all(1))[0]) + 1} holds NaN/inf")
    norms = np.linalg.norm(vals[:, 3:7], axis=1)
    if (norms < 1e-6).any():
        raise DataFormatError(f"{path}: pose {int(np.flatnonzero(norms < 1e-6)[0]) + 1} has a zero quaternion")
    poses = np.tile(np.eye(4), (len(vals), 1, 1))
    poses[:, :3, 3] = vals[:, :3]
    poses[:, :3, :3] = Rotation.from_quat(vals[:, 3:7]).as_matrix()
    return keys, _checked_poses(path, poses)
