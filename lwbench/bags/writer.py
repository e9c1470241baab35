"""Writing clouds into a bag an RViz user replays: ROS 2 (MCAP or SQLite) or ROS 1.

Each cloud becomes a ``sensor_msgs/PointCloud2`` (float32 x y z [intensity] [time], uint16
[ring]) on its topic with its header stamp and log time; a cloud with a pose adds a
``/tf`` message *world -> frame_id* at the same stamp, so RViz places it in the world frame;
the sensor table goes once on ``/lwbench/sensor`` (``std_msgs/String``, JSON), so lwbench
reading the bag back uses the exact model.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError, ParameterError
from lwbench.frame import Frame
from lwbench.sensors.model import SensorModel

from .cloud import cloud_layout
from .reader import POINTCLOUD2, SENSOR_TOPIC, STRING, TF_MESSAGE, rosbags_module
from .tf import quaternion

__all__ = ["BagCloud", "BAG_STORAGES", "DEFAULT_TOPIC", "frames_to_clouds", "write_bag"]

BAG_STORAGES = ("mcap", "sqlite3", "ros1")
DEFAULT_TOPIC = "/lwbench/points"
DEFAULT_FRAME_ID = "lidar"


@dataclass
class BagCloud:
    """One cloud to write; missing stamps and names take defaults (see :func:`write_bag`)."""

    points: np.ndarray
    stamp_ns: int | None = None
    log_ns: int | None = None
    topic: str | None = None
    frame_id: str | None = None
    pose: np.ndarray | None = None
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    time: np.ndarray | None = None


def frames_to_clouds(frames: Sequence[Frame], *, topic: str = DEFAULT_TOPIC, frame_id: str = DEFAULT_FRAME_ID,
                     t0_ns: int = 1_000_000_000) -> list[BagCloud]:
    """Frames as bag clouds: stamps ``t0 + timestamp`` (ROS time 0 means "unset" to tf2)."""
    return [BagCloud(f.points, t0_ns + int(round(f.timestamp * 1e9)), None, topic, frame_id, f.pose,
                     f.intensity, f.ring, f.time) for f in frames]


def _stamp(ns: int) -> tuple[int, int]:
    return ns // 1_000_000_000, ns % 1_000_000_000


class _Messages:
    """The few message types written, built for ROS 2 (CDR) or ROS 1."""

    def __init__(self, ros1: bool) -> None:
        typesys = rosbags_module("rosbags.typesys")
        self.ros1 = ros1
        self.ts = typesys.get_typestore(typesys.Stores.ROS1_NOETIC if ros1 else typesys.Stores.ROS2_HUMBLE)
        if TF_MESSAGE not in self.ts.types:  # rosbags' Noetic store has no tf2_msgs
            self.ts.register(typesys.get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
        self.seq = 0

    def t(self, name: str):
        return self.ts.types[name]

    def header(self, ns: int, frame_id: str):
        sec, nsec = _stamp(ns)
        stamp = self.t("builtin_interfaces/msg/Time")(sec=sec, nanosec=nsec)
        if self.ros1:
            self.seq += 1
            return self.t("std_msgs/msg/Header")(seq=self.seq, stamp=stamp, frame_id=frame_id)
        return self.t("std_msgs/msg/Header")(stamp=stamp, frame_id=frame_id)

    def cloud(self, c: BagCloud, ns: int, frame_id: str):
        pts = np.asarray(c.points, dtype=np.float32).reshape(-1, 3)
        fields, step, data = cloud_layout(pts, c.intensity, c.ring, c.time)
        pf = self.t("sensor_msgs/msg/PointField")
        return self.t(POINTCLOUD2)(
            header=self.header(ns, frame_id), height=1, width=len(pts),
            fields=[pf(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
            is_bigendian=False, point_step=step, row_step=step * len(pts),
            data=np.frombuffer(data, dtype=np.uint8), is_dense=True,
        )

    def tf(self, pose: np.ndarray, ns: int, world: str, frame_id: str):
        q = quaternion(pose)
        t = self.t
        transform = t("geometry_msgs/msg/Transform")(
            translation=t("geometry_msgs/msg/Vector3")(x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3])),
            rotation=t("geometry_msgs/msg/Quaternion")(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
        )
        stamped = t("geometry_msgs/msg/TransformStamped")(
            header=self.header(ns, world), child_frame_id=frame_id, transform=transform)
        return t(TF_MESSAGE)(transforms=[stamped])

    def string(self, text: str):
        return self.t(STRING)(data=text)

    def serialize(self, msg, msgtype: str) -> bytes:
        return bytes(self.ts.serialize_ros1(msg, msgtype) if self.ros1 else self.ts.serialize_cdr(msg, msgtype))


def write_bag(
    out: str | Path,
    clouds: Sequence[BagCloud],
    *,
    sensor: SensorModel | None = None,
    storage: str = "mcap",
    world_frame: str = "world",
    rate_hz: float | None = None,
) -> Path:
    """Write ``clouds`` to a new bag at ``out`` and return its path.

    ``storage``: ``mcap`` or ``sqlite3`` (a rosbag2 folder at ``out``), ``ros1`` (a ``.bag``
    file at ``out``). A cloud without a stamp is stamped ``1 s + i / rate`` (the sensor's rate
    by default); without a topic or frame id it goes on ``/lwbench/points`` in frame ``lidar``.
    """
    storage = "sqlite3" if storage == "db3" else storage
    if storage not in BAG_STORAGES:
        raise ParameterError(f"bag storage must be one of {', '.join(BAG_STORAGES)}, got {storage!r}")
    out = Path(out)
    if out.exists():
        raise DataFormatError(f"{out} exists: a bag is written to a new path")
    rate = rate_hz or (sensor.rate_hz if sensor is not None else 10.0)
    msgs = _Messages(ros1=storage == "ros1")
    rows = []
    for i, c in enumerate(clouds):
        ns = c.stamp_ns if c.stamp_ns is not None else 1_000_000_000 + int(round(i * 1e9 / rate))
        rows.append((c, ns, c.log_ns if c.log_ns is not None else ns, c.topic or DEFAULT_TOPIC,
                     c.frame_id or DEFAULT_FRAME_ID))
    if storage == "ros1":
        writer = rosbags_module("rosbags.rosbag1").Writer(out)
    else:
        r2 = rosbags_module("rosbags.rosbag2")
        plugin = r2.StoragePlugin.MCAP if storage == "mcap" else r2.StoragePlugin.SQLITE3
        writer = r2.Writer(out, version=8, storage_plugin=plugin)
    with writer:
        conns: dict[tuple[str, str], object] = {}

        def write(topic: str, msgtype: str, msg, log_ns: int) -> None:
            if (topic, msgtype) not in conns:
                conns[(topic, msgtype)] = writer.add_connection(topic, msgtype, typestore=msgs.ts)
            writer.write(conns[(topic, msgtype)], log_ns, msgs.serialize(msg, msgtype))

        first = min((r[2] for r in rows), default=1_000_000_000)
        if sensor is not None:
            write(SENSOR_TOPIC, STRING, msgs.string(json.dumps(sensor.to_dict(full=True))), first)
        for c, ns, log_ns, topic, frame_id in rows:
            if c.pose is not None:
                write("/tf", TF_MESSAGE, msgs.tf(np.asarray(c.pose, dtype=np.float64), ns, world_frame, frame_id),
                      log_ns)
            write(topic, POINTCLOUD2, msgs.cloud(c, ns, frame_id), log_ns)
    return out
