"""A small tf buffer: where a cloud's frame was, in the world, at the cloud's stamp.

``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``) and ``nav_msgs/Odometry`` each give edges
*parent -> child* (the child's pose in the parent). As in tf2, a frame has one parent; a lookup
walks from the cloud's ``frame_id`` up to the world frame (given, or the tree's root) and
composes the edges, each dynamic one interpolated at the stamp (translation linearly, rotation
by slerp). A stamp outside an edge's samples by more than ``tolerance_ns`` has no pose: lwbench
never extrapolates a trajectory.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["TransformBuffer", "matrix", "quaternion"]


def matrix(translation: tuple[float, float, float], quat_xyzw: tuple[float, float, float, float]) -> np.ndarray:
    """A 4x4 pose from a translation and a (x, y, z, w) quaternion (ROS order)."""
    from scipy.spatial.transform import Rotation

    t = np.eye(4)
    t[:3, :3] = Rotation.from_quat(np.asarray(quat_xyzw, dtype=np.float64)).as_matrix()
    t[:3, 3] = translation
    return t


def quaternion(pose: np.ndarray) -> np.ndarray:
    """The (x, y, z, w) quaternion of a 4x4 pose's rotation."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(pose, dtype=np.float64)[:3, :3]).as_quat()


@dataclass
class _Edge:
    parent: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)

    _sorted: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, stamp: int, pose: np.ndarray) -> None:
        self.stamps.append(stamp)
        self.poses.append(pose)
        self._sorted = None

    def at(self, stamp: int, tolerance: int) -> np.ndarray | None:
        if self.static:
            return self.poses[-1]
        if self._sorted is None:
            order = np.argsort(self.stamps, kind="stable")
            self._sorted = (order, np.asarray(self.stamps, dtype=np.int64)[order])
        order, stamps = self._sorted
        j = int(np.searchsorted(stamps, stamp))
        if j < len(stamps) and stamps[j] == stamp:
            return self.poses[order[j]]
        if j == 0:
            return self.poses[order[0]] if stamps[0] - stamp <= tolerance else None
        if j == len(stamps):
            return self.poses[order[-1]] if stamp - stamps[-1] <= tolerance else None
        a, b = self.poses[order[j - 1]], self.poses[order[j]]
        w = (stamp - stamps[j - 1]) / (stamps[j] - stamps[j - 1])
        return _interpolate(a, b, float(w))


def _interpolate(a: np.ndarray, b: np.ndarray, w: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation, Slerp

    out = np.eye(4)
    out[:3, 3] = (1 - w) * a[:3, 3] + w * b[:3, 3]
    out[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))([w]).as_matrix()[0]
    return out


class TransformBuffer:
    """Edges by child frame; :meth:`lookup` gives a frame's world pose at a stamp."""

    def __init__(self) -> None:
        self.edges: dict[str, _Edge] = {}
        self.conflicts: set[str] = set()  # children offered a second parent (ignored, as tf2 does)

    def add(self, parent: str, child: str, stamp_ns: int, pose: np.ndarray, *, static: bool = False) -> None:
        parent, child = parent.lstrip("/"), child.lstrip("/")
        if not parent or not child or parent == child:
            return
        edge = self.edges.get(child)
        if edge is None:
            edge = self.edges[child] = _Edge(parent, static)
        elif edge.parent != parent:
            self.conflicts.add(child)
            return
        if static:
            edge.static, edge.stamps, edge.poses = True, [stamp_ns], [pose]
        elif not edge.static:
            edge.add(stamp_ns, pose)

    def chain(self, frame: str, world: str | None = None) -> list[str] | None:
        """Frames from ``frame`` up to ``world`` (or the root), or None if ``world`` is not above it."""
        frame = frame.lstrip("/")
        out, seen = [frame], {frame}
        while out[-1] != world and out[-1] in self.edges:
            parent = self.edges[out[-1]].parent
            if parent in seen:
                return None  # a cycle
            out.append(parent)
            seen.add(parent)
        if world is not None and out[-1] != world:
            return None
        return out

    def root(self, frame: str) -> str | None:
        chain = self.chain(frame)
        return chain[-1] if chain else None

    def moves(self, frame: str, world: str | None = None) -> bool:
        """Whether the chain from ``frame`` to the world holds a dynamic edge (a trajectory; a
        chain of static mounts alone says nothing about where the sensor went)."""
        chain = self.chain(frame, world)
        return bool(chain) and any(not self.edges[c].static for c in chain[:-1])

    def lookup(self, frame: str, stamp_ns: int, world: str | None = None, tolerance_ns: int = 0) -> np.ndarray | None:
        """``T_world_frame`` at ``stamp_ns``, or None where a link is missing."""
        chain = self.chain(frame, world)
        if chain is None:
            return None
        pose = np.eye(4)
        for child in chain[:-1]:
            t = self.edges[child].at(stamp_ns, tolerance_ns)
            if t is None:
                return None
            pose = t @ pose
        return pose
