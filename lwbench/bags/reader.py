"""The ``rosbag`` dataset: ``sensor_msgs/PointCloud2`` scans from ROS 2 (``.db3``, ``.mcap``, a
rosbag2 folder) and ROS 1 (``.bag``) recordings, read with ``rosbags`` (pure Python, no ROS).

- **Topic**: ``topic=...``, or the bag's only PointCloud2 topic (several: an error naming them).
- **Fields** by name (:mod:`.cloud`): x, y, z, intensity, ring, per-point time.
- **Poses** (sensor -> world at each cloud's header stamp) from ``/tf`` + ``/tf_static``, else
  from a ``nav_msgs/Odometry`` topic (with ``/tf_static`` for the sensor's mount); ``pose_topic``
  picks one, ``none`` turns poses off; ``world_frame`` stops the chain below the tree's root.
  A dataset has poses only if every cloud has one.
- **Sensor** (``sensor=auto``): the ``/lwbench/sensor`` table lwbench writes into its bags, else
  a ``sensor.json`` beside the bag, else derived from the first cloud as the file loaders do.

Reading never writes: rosbags opens SQLite bags with ``immutable=1`` (no journal, no WAL), and
:meth:`BagDataset.sniff` refuses an lwbench results store (also SQLite) by its schema.
Clouds are read in order with one open reader; asking for an earlier frame starts a new pass
(the runner reads frames in order), so a large bag is never held in memory.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lwbench.dataset import Dataset
from lwbench.errors import DataFormatError, LwbenchError, MissingDependencyError, ParameterError
from lwbench.frame import Frame
from lwbench.io import SENSOR_FILE, ScanArrays, read_sensor_file
from lwbench.params import Param
from lwbench.sensors.model import SENSOR_PRESETS, SensorModel, get_sensor

from .cloud import cloud_arrays
from .tf import TransformBuffer, matrix

__all__ = ["BagDataset", "BAG_SUFFIXES", "SENSOR_TOPIC", "POINTCLOUD2", "open_reader"]

BAG_SUFFIXES = (".db3", ".mcap", ".bag")
SENSOR_TOPIC = "/lwbench/sensor"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
STRING = "std_msgs/msg/String"


def rosbags_module(name: str):
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise MissingDependencyError(
            f"reading and writing ROS bags needs the rosbags library ({exc}); pip install 'rosbags>=0.10'"
        ) from None


def open_reader(path: Path):
    """An open ``rosbags`` AnyReader for a bag file or rosbag2 folder, with the ROS 2 Humble /
    ROS 1 Noetic message definitions for bags that carry none (close it, or use ``with``)."""
    anyreader = rosbags_module("rosbags.highlevel")
    typesys = rosbags_module("rosbags.typesys")
    store = typesys.Stores.ROS1_NOETIC if path.suffix == ".bag" else typesys.Stores.ROS2_HUMBLE
    try:
        reader = anyreader.AnyReader([path], default_typestore=typesys.get_typestore(store))
        reader.open()
    except Exception as exc:  # noqa: BLE001 - rosbags' own errors, missing metadata, ...: one clear line
        raise DataFormatError(f"{path}: not a ROS bag rosbags can read ({type(exc).__name__}: {exc})") from None
    return reader


def _cdr_header(raw: bytes | memoryview) -> tuple[int, str] | None:
    """Stamp (ns) and frame id of a ROS 2 message that starts with a ``std_msgs/Header``, read
    from its CDR bytes without deserializing the cloud behind it; None if it does not parse."""
    import struct

    raw = bytes(raw[:4096])
    if len(raw) < 16 or raw[1] not in (0, 1):
        return None
    e = "<" if raw[1] == 1 else ">"
    sec, nsec, n = struct.unpack_from(e + "iII", raw, 4)
    if n == 0 or 16 + n > len(raw) or nsec >= 1_000_000_000:
        return None
    return sec * 1_000_000_000 + nsec, raw[16 : 16 + n - 1].decode("utf-8", errors="replace")


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


@dataclass(frozen=True)
class _Cloud:
    log_ns: int
    stamp_ns: int
    frame_id: str


def _content_digest(path: Path) -> str:
    """SHA-256 over every file of the bag (names and bytes): results follow the data, not where it lies."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        h.update(f.name.encode() + b"\0")
        with open(f, "rb") as fh:
            while block := fh.read(1 << 20):
                h.update(block)
    return h.hexdigest()


class BagDataset(Dataset):
    """PointCloud2 scans of a ROS bag, with tf / odometry poses (see the module docstring)."""

    name = "rosbag"
    description = "ROS 2 bag (.db3, .mcap, rosbag2 folder) or ROS 1 .bag: PointCloud2 scans, tf/odometry poses"
    params = (
        Param("path", "str", None, "bag file or rosbag2 folder"),
        Param("topic", "str", None, "PointCloud2 topic (default: the bag's only one)"),
        Param("pose_topic", "str", "auto", "auto (/tf, else an Odometry topic), none, or a TFMessage/Odometry topic"),
        Param("world_frame", "str", None, "frame the poses are in (default: the root of the cloud frame's tree)"),
        Param("pose_tolerance", "float", 0.1, "s a cloud stamp may lie outside the pose samples", low=0.0),
        Param("sensor", "str", "auto", "sensor model: auto, a preset name, or a sensor.json path"),
        Param("rate_hz", "float", None, "frame rate (default: from the cloud stamps)", low=0.01),
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        if not self.config["path"]:
            raise DataFormatError("rosbag: the path parameter is required")
        self.path = Path(self.config["path"])
        if not self.path.exists():
            raise DataFormatError(f"rosbag: {self.path} does not exist")
        self._cursor: tuple[Any, Iterator, int] | None = None  # (reader, messages, next index)
        self._derivation: Any = None  # the lwbench.sensors.derive.Derivation, when the sensor was derived
        reader = open_reader(self.path)
        try:
            self.topic, conns = self._pick_topic(reader)
            self._clouds = list(self._headers(reader, conns))
            self._sensor_table = self._sensor_message(reader)
            self.poses, self.pose_source, self.world = self._load_poses(reader)
        except LwbenchError:
            raise
        except Exception as exc:  # noqa: BLE001 - a damaged bag is bad input, not an lwbench bug
            raise DataFormatError(f"rosbag: {self.path}: unreadable ({type(exc).__name__}: {exc})") from None
        finally:
            reader.close()
        if not self._clouds:
            raise DataFormatError(f"rosbag: {self.path}: no messages on {self.topic}")
        if self.config["sensor"] != "auto":
            _ = self.sensor  # a typo in sensor= is one clear error now, not one per frame

    # -- reading the index ----------------------------------------------------------------------
    def _pick_topic(self, reader) -> tuple[str, list]:
        clouds = sorted({c.topic for c in reader.connections if c.msgtype == POINTCLOUD2})
        want = self.config["topic"]
        if want is not None:
            if want not in clouds:
                raise ParameterError(
                    f"rosbag: {self.path} has no PointCloud2 topic {want!r} (PointCloud2 topics: "
                    f"{', '.join(clouds) or 'none'})"
                )
            topic = want
        elif len(clouds) == 1:
            topic = clouds[0]
        elif not clouds:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections})) or "none"
            raise DataFormatError(f"rosbag: {self.path} has no sensor_msgs/PointCloud2 topic (topics: {have})")
        else:
            raise ParameterError(
                f"rosbag: {self.path} has {len(clouds)} PointCloud2 topics ({', '.join(clouds)}); "
                "pick one with --dataset-param topic=..."
            )
        return topic, [c for c in reader.connections if c.topic == topic]

    def _headers(self, reader, conns) -> Iterator[_Cloud]:
        for conn, t, raw in reader.messages(connections=conns):
            head = _cdr_header(raw) if reader.is2 else None
            if head is None:
                msg = reader.deserialize(raw, conn.msgtype)
                head = (_stamp_ns(msg.header), msg.header.frame_id)
            yield _Cloud(t, *head)

    def _sensor_message(self, reader) -> dict | None:
        conns = [c for c in reader.connections if c.topic == SENSOR_TOPIC and c.msgtype == STRING]
        if not conns:
            return None
        for conn, _, raw in reader.messages(connections=conns):
            try:
                table = json.loads(reader.deserialize(raw, conn.msgtype).data)
            except (ValueError, TypeError):
                raise DataFormatError(f"rosbag: {self.path}: {SENSOR_TOPIC} does not hold a sensor table") from None
            return table if isinstance(table, dict) else None
        return None

    def _load_poses(self, reader) -> tuple[np.ndarray | None, str | None, str | None]:
        choice = self.config["pose_topic"]
        if choice == "none":
            return None, None, None
        by_type: dict[str, list] = {}
        for c in reader.connections:
            by_type.setdefault(c.msgtype, []).append(c)
        tf_conns = by_type.get(TF_MESSAGE, [])
        static = [c for c in tf_conns if c.topic.rstrip("/").endswith("tf_static")]
        dynamic = [c for c in tf_conns if c not in static]
        odometry = by_type.get(ODOMETRY, [])
        if choice == "auto":
            attempts = [("/tf", dynamic)] if dynamic else []
            attempts += [(c.topic, [c]) for c in sorted(odometry, key=lambda c: c.topic)]
        else:
            named = [c for c in dynamic + odometry if c.topic == choice]
            if not named:
                raise ParameterError(
                    f"rosbag: pose_topic {choice!r} is not a TFMessage or Odometry topic of {self.path} "
                    f"(have: {', '.join(sorted({c.topic for c in dynamic + odometry})) or 'none'})"
                )
            attempts = [(choice, named)]
        for label, conns in attempts:
            buffer = TransformBuffer()
            self._fill(reader, buffer, static, static=True)
            self._fill(reader, buffer, conns, static=False)
            poses, world = self._locate(buffer)
            if poses is not None:
                return poses, f"{label}" + (" + /tf_static" if static else ""), world
        return None, None, None

    @staticmethod
    def _fill(reader, buffer: TransformBuffer, conns: list, *, static: bool) -> None:
        if not conns:
            return  # (rosbags reads every topic when given no connections)
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.msgtype == ODOMETRY:
                p = msg.pose.pose
                pose = matrix((p.position.x, p.position.y, p.position.z),
                              (p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w))
                buffer.add(msg.header.frame_id, msg.child_frame_id, _stamp_ns(msg.header), pose, static=static)
                continue
            for ts in msg.transforms:
                tr, q = ts.transform.translation, ts.transform.rotation
                pose = matrix((tr.x, tr.y, tr.z), (q.x, q.y, q.z, q.w))
                buffer.add(ts.header.frame_id, ts.child_frame_id, _stamp_ns(ts.header), pose, static=static)

    def _locate(self, buffer: TransformBuffer) -> tuple[np.ndarray | None, str | None]:
        world = self.config["world_frame"]
        tol = int(round(self.config["pose_tolerance"] * 1e9))
        poses = []
        for c in self._clouds:
            if not buffer.moves(c.frame_id, world):
                return None, None
            pose = buffer.lookup(c.frame_id, c.stamp_ns, world, tol)
            if pose is None:
                return None, None
            poses.append(pose)
        return np.stack(poses), world or buffer.root(self._clouds[0].frame_id)

    # -- the Dataset API --------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._clouds)

    @property
    def has_poses(self) -> bool:
        return self.poses is not None

    @cached_property
    def rate_hz(self) -> float:
        if self.config["rate_hz"]:
            return float(self.config["rate_hz"])
        stamps = np.array([c.stamp_ns for c in self._clouds], dtype=np.int64)
        steps = np.diff(np.sort(stamps))
        steps = steps[steps > 0]
        return float(1e9 / np.median(steps)) if len(steps) else 10.0

    @cached_property
    def sensor_source(self) -> str:
        _ = self.sensor
        return self._sensor_source

    @cached_property
    def sensor(self) -> SensorModel:
        value = self.config["sensor"]
        folder = self.path if self.path.is_dir() else self.path.parent
        if value == "auto":
            if self._sensor_table is not None:
                self._sensor_source = f"{SENSOR_TOPIC} in the bag"
                try:
                    return SensorModel.from_dict(self._sensor_table)
                except (KeyError, TypeError, ValueError) as exc:
                    raise DataFormatError(f"rosbag: {self.path}: bad sensor table on {SENSOR_TOPIC} ({exc})") from None
            if (folder / SENSOR_FILE).is_file():
                self._sensor_source = f"{SENSOR_FILE} beside the bag"
                return read_sensor_file(folder / SENSOR_FILE)
            from lwbench.sensors.derive import derive_sensor

            scan = self._scan(0)
            if len(scan.points) < 100:
                raise DataFormatError(
                    f"rosbag: the first cloud has {len(scan.points)} points, too few to derive a sensor model "
                    "from; pass --dataset-param sensor=<preset or sensor.json path>"
                )
            d = derive_sensor(scan.points, ring=scan.ring, rate_hz=self.rate_hz, name="derived")
            self._sensor_source = f"derived from the first cloud ({d.method})"
            self._derivation = d
            return d.sensor
        if value.lower() in SENSOR_PRESETS:
            self._sensor_source = f"preset {value.lower()}"
            return get_sensor(value)
        path = Path(value).expanduser()
        if path.is_file():
            self._sensor_source = f"file {path}"
            return read_sensor_file(path)
        raise ParameterError(
            f"sensor={value!r}: neither a preset ({', '.join(sorted(SENSOR_PRESETS))}), auto, nor a sensor.json file"
        )

    @property
    def sensor_guessed(self) -> bool:
        """Whether the sensor model was guessed from the first cloud (no sensor table, no
        sensor.json, no ring field or ring order): the rows scored on it say so."""
        _ = self.sensor
        return self._derivation is not None and self._derivation.guessed

    def _scan(self, index: int) -> ScanArrays:
        """Cloud ``index``, read on from the open pass (or from a new one when going back)."""
        if self._cursor is None or self._cursor[2] > index:
            self.close()
            reader = open_reader(self.path)
            conns = [c for c in reader.connections if c.topic == self.topic]
            self._cursor = (reader, reader.messages(connections=conns), 0)
        reader, messages, at = self._cursor
        where = f"rosbag {self.path.name} {self.topic} message {index}"
        try:
            for conn, _, raw in messages:
                if at == index:
                    self._cursor = (reader, messages, at + 1)
                    return cloud_arrays(reader.deserialize(raw, conn.msgtype), where)
                at += 1
        except LwbenchError:
            raise
        except Exception as exc:  # noqa: BLE001 - see __init__
            self.close()
            raise DataFormatError(f"{where}: unreadable ({type(exc).__name__}: {exc})") from None
        self.close()
        raise IndexError(f"rosbag: message {index} of {self.topic} is missing from {self.path}")

    def pose(self, index: int) -> np.ndarray | None:
        """From tf / odometry, read when the bag was opened: no cloud is read."""
        return None if self.poses is None else self.poses[index % len(self)]

    def frame(self, index: int) -> Frame:
        if not 0 <= index < len(self):
            raise IndexError(f"rosbag: frame {index} out of range (0..{len(self) - 1})")
        scan = self._scan(index)
        c = self._clouds[index]
        return Frame(scan.points, self.sensor, index=index, timestamp=c.stamp_ns * 1e-9,
                     pose=None if self.poses is None else self.poses[index],
                     intensity=scan.intensity, ring=scan.ring, time=scan.time)

    def close(self) -> None:
        if self._cursor is not None:
            try:
                self._cursor[0].close()
            finally:
                self._cursor = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001, S110 - interpreter shutdown
            pass

    def frame_origin(self, index: int) -> dict[str, Any]:
        c = self._clouds[index]
        return {"name": f"{self.topic.strip('/').replace('/', '_')}_{c.stamp_ns}", "stamp_ns": c.stamp_ns,
                "log_ns": c.log_ns, "topic": self.topic, "frame_id": c.frame_id, "world_frame": self.world}

    def identity(self) -> str:
        """The bag's bytes and the reading parameters -- not its path: a copied bag is the same data."""
        what = {k: v for k, v in self.config.items() if k != "path"}
        h = hashlib.sha256(json.dumps(what, sort_keys=True, default=str).encode())
        h.update(_content_digest(self.path).encode())
        return f"{self.name}:{h.hexdigest()[:16]}"

    def source_info(self) -> dict[str, Any]:
        return {"layout": f"ROS bag, topic {self.topic}", "poses from": self.pose_source or "none",
                "world frame": self.world or "none", "sensor source": self.sensor_source,
                "sensor guessed": self.sensor_guessed}

    @classmethod
    def sniff(cls, path: Path) -> bool:
        try:
            if path.is_dir():
                return (path / "metadata.yaml").is_file()
            if path.suffix.lower() not in BAG_SUFFIXES or not path.is_file():
                return False
            if path.suffix.lower() == ".db3":
                from lwbench.results.store import is_results_store

                return not is_results_store(path)
            return True
        except OSError:
            return False
