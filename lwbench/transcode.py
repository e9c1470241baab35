"""``lwbench encode`` / ``lwbench decode``: payloads to files and back, exactly as a run does.

Encoding uses the run's own codec configuration (:func:`lwbench.run.expand_codec_configs`: the
same defaults, validation and seed policy), and decoding a fresh codec instance built from the
stream header's parameters -- what :func:`lwbench.run.evaluate.encode_decode` does -- so a cloud
decoded from a file is the cloud the run scored. Decoded clouds go out as binary PCD or PLY
(float32 x,y,z, written here byte for byte, so they read back exactly) named after their source
frames, with ``sensor.json`` and ``poses.txt`` beside them (the folder is then a dataset
``lwbench run`` reads), or into a ROS 2 bag on the source's topics and stamps.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lwbench.codec import Codec
from lwbench.dataset import Dataset
from lwbench.errors import DataFormatError, LwbenchError, ParameterError
from lwbench.io import SENSOR_FILE
from lwbench.params import resolve_params
from lwbench.payload import Payload
from lwbench.registry import Registry
from lwbench.run.evaluate import decoded_cloud
from lwbench.run.plan import CodecConfig, expand_codec_configs
from lwbench.streamfile import (
    STREAM_SUFFIX,
    FolderWriter,
    FrameEntry,
    PayloadSource,
    StreamHeader,
    StreamWriter,
)

__all__ = [
    "CLOUD_FORMATS",
    "DecodedFrame",
    "EncodeSummary",
    "codec_config",
    "decode_payloads",
    "decoded_frames",
    "encode_dataset",
    "write_pcd",
    "write_ply",
]

CLOUD_FORMATS = ("pcd", "ply", "bag")


def _assignments(items: Sequence[str], codec: str) -> dict[str, str]:
    """``KEY=VALUE`` or ``CODEC.KEY=VALUE`` words (one codec, one value each)."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        owner, dot, name = key.partition(".")
        if dot:
            if owner.strip() != codec:
                raise ParameterError(f"--param {item!r} is for codec {owner.strip()!r}, not {codec!r}")
            key = name
        if not sep or not key.strip():
            raise ParameterError(f"--param must look like KEY=VALUE (or {codec}.KEY=VALUE), got {item!r}")
        if "," in value:
            raise ParameterError(f"--param {item!r}: one value only (lwbench run sweeps; encode writes one stream)")
        out[key.strip()] = value.strip()
    return out


def codec_config(registry: Registry, codec: str, params: Sequence[str], seed: int = 0) -> CodecConfig:
    """The configuration ``lwbench run --codec CODEC --param ... --seed SEED`` would evaluate."""
    cls = registry.codec(codec)
    values = {k: [v] for k, v in _assignments(params, codec).items()}
    (config,) = expand_codec_configs(cls, values, seed)
    return config


# ---------------------------------------------------------------------------------- encode
@dataclass
class EncodeSummary:
    path: Path
    layout: str
    frames: int = 0
    payload_bytes: int = 0
    raw_bytes: int = 0


def encode_dataset(
    registry: Registry,
    dataset: Dataset,
    config: CodecConfig,
    out: Path,
    *,
    stream: bool = False,
    frames: int | None = None,
    source: str = "",
    on_frame: Callable[[int, int], None] | None = None,
) -> EncodeSummary:
    """Encode the first ``frames`` frames of ``dataset`` into ``out`` (a folder): one ``.lwb``
    per frame plus ``stream.json``, or with ``stream=True`` one ``<codec>.lwbs`` stream file."""
    codec_cls = registry.codec(config.name)
    encoder = codec_cls(**config.params)
    n = min(len(dataset), frames) if frames else len(dataset)
    first = dataset[0]
    header = StreamHeader.for_sensors(config.name, config.params, [first.sensor], source=source,
                                      world_frame=dataset.frame_origin(0).get("world_frame"))
    out.mkdir(parents=True, exist_ok=True)
    if stream:
        writer: StreamWriter | FolderWriter = StreamWriter(out / f"{config.name}{STREAM_SUFFIX}", header)
    else:
        writer = FolderWriter(out, header)
    summary = EncodeSummary(writer.path, "stream file" if stream else "payload folder")
    with writer:
        for i in range(n):
            frame = first if i == 0 else dataset[i]
            payload = encoder.encode(frame)
            if not isinstance(payload, (bytes, bytearray)):
                raise LwbenchError(f"{config.name}: encode returned {type(payload).__name__}, not bytes")
            origin = dict(dataset.frame_origin(i))
            name = str(origin.pop("name", f"{i:06d}"))
            writer.add(bytes(payload), i, name, sensor=frame.sensor, **origin)
            summary.frames += 1
            summary.payload_bytes += len(payload)
            summary.raw_bytes += frame.raw_bytes
            if on_frame is not None:
                on_frame(i + 1, n)
    return summary


# ---------------------------------------------------------------------------------- decode
@dataclass
class DecodedFrame:
    entry: FrameEntry
    points: np.ndarray
    pose: np.ndarray | None
    payload_bytes: int


@dataclass
class DecodeSummary:
    out: Path
    codec: str
    frames: int = 0
    points: int = 0
    files: list[Path] = field(default_factory=list)


def _decoder(registry: Registry, source: PayloadSource, overrides: Sequence[str]) -> tuple[type[Codec], dict]:
    if source.header is not None:
        codec, params = source.header.codec, dict(source.header.params)
    else:
        codec, params = Payload.from_bytes(source.read(0)).codec_id, {}
    cls = registry.codec(codec)
    params.update(_assignments(overrides, codec))
    return cls, resolve_params(codec, cls.all_params(), params)


def decoded_frames(
    registry: Registry, source: PayloadSource, overrides: Sequence[str] = ()
) -> tuple[str, list[DecodedFrame]]:
    """Decode every payload of ``source`` with a fresh codec built from its stream header."""
    sensors = source.sensors()
    cls, params = _decoder(registry, source, overrides)
    out = []
    for entry, data in source:
        try:
            payload = Payload.from_bytes(data)
            points = decoded_cloud(cls.name, cls(**params).use_sensors(sensors).decode(data))
        except LwbenchError as exc:
            raise type(exc)(f"{source.path}: frame {entry.name}: {exc}") from None
        out.append(DecodedFrame(entry, points, payload.pose, len(data)))
    return cls.name, out


def decode_payloads(
    registry: Registry,
    source: PayloadSource,
    out: Path,
    *,
    fmt: str = "pcd",
    overrides: Sequence[str] = (),
    storage: str = "mcap",
) -> DecodeSummary:
    """Decode ``source`` and write the clouds: ``out/<name>.<codec>.pcd|ply`` (+ ``sensor.json``,
    ``poses.txt``), or with ``fmt="bag"`` a ROS 2 bag at ``out`` (which must not exist)."""
    if fmt not in CLOUD_FORMATS:
        raise ParameterError(f"--format must be one of {', '.join(CLOUD_FORMATS)}, got {fmt!r}")
    if fmt == "bag" and out.exists():
        raise DataFormatError(f"{out} exists: a bag is written to a new folder (rosbag2 layout)")
    codec, frames = decoded_frames(registry, source, overrides)
    sensors = source.sensors()
    summary = DecodeSummary(out, codec, len(frames), sum(len(f.points) for f in frames))
    if fmt == "bag":
        from lwbench.bags import BagCloud, write_bag

        world = (source.header.world_frame if source.header is not None else None) or "world"
        clouds = [BagCloud(f.points, f.entry.stamp_ns, f.entry.log_ns, f.entry.topic, f.entry.frame_id, f.pose)
                  for f in frames]
        summary.files.append(write_bag(out, clouds, sensor=sensors[0] if len(sensors) == 1 else None,
                                       storage=storage, world_frame=world))
        return summary
    out.mkdir(parents=True, exist_ok=True)
    writer = write_pcd if fmt == "pcd" else write_ply
    for f in frames:
        path = out / f"{f.entry.name}.{codec}.{fmt}"
        writer(path, f.points)
        summary.files.append(path)
    if len(sensors) == 1:
        (out / SENSOR_FILE).write_text(json.dumps(sensors[0].to_dict(full=True), indent=1))
    if frames and all(f.pose is not None for f in frames):
        rows = np.array([f.pose[:3, :4].reshape(-1) for f in frames])
        np.savetxt(out / "poses.txt", rows, fmt="%.9e")
    return summary


# ------------------------------------------------------------------------------ cloud files
def _xyz(points: np.ndarray) -> np.ndarray:
    pts = np.ascontiguousarray(points, dtype="<f4")
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    return pts


def write_pcd(path: str | Path, points: np.ndarray) -> Path:
    """Binary PCD v0.7, float32 x y z: what PCL, Open3D and CloudCompare read."""
    pts = _xyz(points)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format (lwbench)\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
        f"TYPE F F F\nCOUNT 1 1 1\nWIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(pts)}\n"
        "DATA binary\n"
    )
    path = Path(path)
    path.write_bytes(header.encode("ascii") + pts.tobytes())
    return path


def write_ply(path: str | Path, points: np.ndarray) -> Path:
    """Binary little-endian PLY, float32 x y z vertices."""
    pts = _xyz(points)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by lwbench\n"
        f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    )
    path = Path(path)
    path.write_bytes(header.encode("ascii") + pts.tobytes())
    return path


def describe_source(registry: Registry, source: PayloadSource) -> dict[str, Any]:
    """What ``lwbench inspect`` shows for a stream file or payload folder."""
    info: dict[str, Any] = {
        "kind": f"lwbench {source.kind}",
        "frames": len(source.entries),
        "payload bytes": sum(e.bytes for e in source.entries),
    }
    if source.header is not None:
        info.update({"codec": source.header.codec, "params": source.header.params, "source": source.header.source})
        info["sensors"] = {sid: t.get("name", "?") for sid, t in source.header.sensors.items()}
    stamps = [e.stamp_ns for e in source.entries if e.stamp_ns is not None]
    if stamps:
        info["stamps (s)"] = [round(min(stamps) * 1e-9, 6), round(max(stamps) * 1e-9, 6)]
    topics = sorted({e.topic for e in source.entries if e.topic})
    if topics:
        info["topics"] = topics
    if source.entries:
        info["first frame"] = source.entries[0].name
        try:
            _, frames = decoded_frames(registry, PayloadSource(
                source.path, source.kind, source.header, source.entries[:1], source.sensor_file))
            pts = frames[0].points
            info["first frame decoded points"] = int(len(pts))
        except LwbenchError as exc:
            info["first frame decoded"] = f"failed: {exc}"
    return info
