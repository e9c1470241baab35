"""Payloads on disk: what ``lwbench encode`` writes and ``lwbench decode`` / ``inspect`` read.

A payload names its sensor by preset or by a 16-hex ``sensor_id`` (the table travels once per
stream, not per frame; see :meth:`lwbench.SensorModel.to_wire`). On disk the "once" is a
*stream header*: the codec, its fully resolved parameters (decode-side settings such as VSGP's
``upsample`` are the receiver's choice, not in the payload) and every sensor table by id. Two
layouts carry it:

- **a folder of payloads**: ``DIR/<name>.lwb`` per frame -- each an ordinary payload, byte for
  byte what crosses the link -- and ``DIR/stream.json`` with the header and the index (each
  frame's file, name, stamps, topic). A lone ``.lwb`` copied elsewhere decodes if a
  ``stream.json`` or an lwbench ``sensor.json`` lies beside it (or its sensor is a preset);
- **one stream file** ``.lwbs``::

      magic "LWBS" | version u8 | header_len u32 | header JSON | crc32 u32
      per frame: payload_len u32 | payload               (the payloads, in order)
      index JSON | index_offset u64 | index_len u32 | crc32 u32 | "LWBE"

  The index sits at the end so that a writer streams frames out as they are encoded; each
  payload is length-prefixed, so a file cut short still shows how far it got.

Everything read is checked (magic, version, lengths, checksums, JSON types) and a bad file is
one :class:`~lwbench.errors.DataFormatError`; nothing here executes code (JSON, never pickle).
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from lwbench.errors import DataFormatError
from lwbench.sensors.model import SensorModel

__all__ = [
    "FrameEntry",
    "PAYLOAD_SUFFIX",
    "PayloadSource",
    "STREAM_JSON",
    "STREAM_SUFFIX",
    "StreamHeader",
    "StreamWriter",
    "FolderWriter",
    "is_stream_file",
    "open_payloads",
]

STREAM_SUFFIX = ".lwbs"
PAYLOAD_SUFFIX = ".lwb"
STREAM_JSON = "stream.json"
MAGIC = b"LWBS"
END_MAGIC = b"LWBE"
FORMAT_VERSION = 1
_HEAD = struct.Struct("<4sBI")
_FOOT = struct.Struct("<QII4s")
_LEN = struct.Struct("<I")
_MAX_JSON = 64 << 20  # an index of a million frames is ~100 MB; refuse absurd lengths up front


@dataclass
class StreamHeader:
    """What a receiver needs once per stream: codec, parameters, sensor tables by id."""

    codec: str
    params: dict[str, Any]
    sensors: dict[str, dict[str, Any]] = field(default_factory=dict)
    source: str = ""
    world_frame: str | None = None

    @classmethod
    def for_sensors(cls, codec: str, params: dict[str, Any], sensors: list[SensorModel], **kw: Any) -> StreamHeader:
        return cls(codec, dict(params), {s.sensor_id: s.to_dict(full=True) for s in sensors}, **kw)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Any, where: str) -> StreamHeader:
        if not isinstance(d, dict):
            raise DataFormatError(f"{where}: the stream header is not a JSON object")
        codec, params, sensors = d.get("codec"), d.get("params", {}), d.get("sensors", {})
        if not isinstance(codec, str) or not codec:
            raise DataFormatError(f"{where}: the stream header names no codec")
        if not isinstance(params, dict) or not isinstance(sensors, dict):
            raise DataFormatError(f"{where}: the stream header's params and sensors must be JSON objects")
        world = d.get("world_frame")
        return cls(codec, params, sensors, str(d.get("source", "")), world if isinstance(world, str) else None)

    def sensor_models(self, where: str) -> list[SensorModel]:
        """The sensor tables, each checked to be the sensor its id names."""
        out = []
        for sid, table in self.sensors.items():
            try:
                sensor = SensorModel.from_dict(table)
            except (KeyError, TypeError, ValueError) as exc:
                raise DataFormatError(f"{where}: sensor {sid!r} has a bad table ({exc})") from None
            if sensor.sensor_id != sid:
                raise DataFormatError(f"{where}: sensor table filed under {sid!r} is sensor {sensor.sensor_id!r}")
            out.append(sensor)
        return out



@dataclass
class FrameEntry:
    """One frame of the index: where its payload is and where the frame came from."""

    index: int
    name: str
    bytes: int
    offset: int | None = None  # stream file: where the payload starts
    file: str | None = None  # folder layout: the payload's file name
    stamp_ns: int | None = None
    log_ns: int | None = None
    topic: str | None = None
    frame_id: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}

    @classmethod
    def from_dict(cls, d: Any, where: str) -> FrameEntry:
        if not isinstance(d, dict):
            raise DataFormatError(f"{where}: an index entry is not a JSON object")
        try:
            entry = cls(**{k: d[k] for k in d if k in cls.__dataclass_fields__})
        except TypeError as exc:
            raise DataFormatError(f"{where}: bad index entry ({exc})") from None
        ints = ("index", "bytes", "offset", "stamp_ns", "log_ns")
        for k in ints:
            v = getattr(entry, k)
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 0):
                raise DataFormatError(f"{where}: index entry field {k!r} must be a non-negative integer")
        for k in ("name", "file", "topic", "frame_id"):
            v = getattr(entry, k)
            if v is not None and not isinstance(v, str):
                raise DataFormatError(f"{where}: index entry field {k!r} must be a string")
        if entry.file is not None and (Path(entry.file).name != entry.file or entry.file in ("", ".", "..")):
            raise DataFormatError(f"{where}: index entry file {entry.file!r} is not a plain file name")
        return entry


def _unique_names(entries: list[FrameEntry], name: str) -> str:
    taken = {e.name for e in entries}
    if name not in taken:
        return name
    i = 1
    while f"{name}_{i}" in taken:
        i += 1
    return f"{name}_{i}"


def _safe_stem(name: str) -> str:
    """A file-name-safe version of a frame name (a ROS topic has slashes)."""
    out = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip("._")
    return out or "frame"


class StreamWriter:
    """Writes one ``.lwbs`` stream file, frame by frame (``with StreamWriter(...) as w: w.add(...)``)."""

    def __init__(self, path: str | Path, header: StreamHeader) -> None:
        self.path = Path(path)
        self.header = header
        self.entries: list[FrameEntry] = []
        self._late_sensors: dict[str, dict[str, Any]] = {}  # met after the header was written
        self._fh: BinaryIO = open(self.path, "wb")
        blob = json.dumps(header.to_dict(), sort_keys=True, separators=(",", ":")).encode()
        self._fh.write(_HEAD.pack(MAGIC, FORMAT_VERSION, len(blob)) + blob + _LEN.pack(zlib.crc32(blob)))

    def note_sensor(self, sensor: SensorModel) -> None:
        """A sensor a payload names (the frame's, or one the encoder derived): its table travels
        in the index, so that a fresh process decodes."""
        if sensor.sensor_id not in self.header.sensors:
            self._late_sensors.setdefault(sensor.sensor_id, sensor.to_dict(full=True))

    def add(self, payload: bytes, index: int, name: str, sensor: SensorModel | None = None,
            **origin: Any) -> FrameEntry:
        if sensor is not None:
            self.note_sensor(sensor)
        self._fh.write(_LEN.pack(len(payload)))
        entry = FrameEntry(index, _unique_names(self.entries, _safe_stem(name)), len(payload), offset=self._fh.tell(),
                           **_origin_fields(origin))
        self._fh.write(payload)
        self.entries.append(entry)
        return entry

    def close(self) -> None:
        if self._fh.closed:
            return
        offset = self._fh.tell()
        index = {"frames": [e.to_dict() for e in self.entries], "sensors": self._late_sensors}
        blob = json.dumps(index, sort_keys=True, separators=(",", ":")).encode()
        self._fh.write(blob + _FOOT.pack(offset, len(blob), zlib.crc32(blob), END_MAGIC))
        self._fh.close()

    def __enter__(self) -> StreamWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class FolderWriter:
    """Writes ``DIR/<name>.lwb`` per frame and ``DIR/stream.json`` (header + index) at the end."""

    def __init__(self, folder: str | Path, header: StreamHeader) -> None:
        self.path = Path(folder)
        self.path.mkdir(parents=True, exist_ok=True)
        self.header = header
        self.entries: list[FrameEntry] = []

    def note_sensor(self, sensor: SensorModel) -> None:
        """A sensor a payload names: its table goes into ``stream.json``."""
        self.header.sensors.setdefault(sensor.sensor_id, sensor.to_dict(full=True))

    def add(self, payload: bytes, index: int, name: str, sensor: SensorModel | None = None,
            **origin: Any) -> FrameEntry:
        if sensor is not None:
            self.note_sensor(sensor)
        name = _unique_names(self.entries, _safe_stem(name))
        file = f"{name}{PAYLOAD_SUFFIX}"
        (self.path / file).write_bytes(payload)
        entry = FrameEntry(index, name, len(payload), file=file, **_origin_fields(origin))
        self.entries.append(entry)
        return entry

    def close(self) -> None:
        doc = {"format": "lwbench payload folder", "version": FORMAT_VERSION, **self.header.to_dict(),
               "frames": [e.to_dict() for e in self.entries]}
        (self.path / STREAM_JSON).write_text(json.dumps(doc, indent=1, sort_keys=True))

    def __enter__(self) -> FolderWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _origin_fields(origin: dict[str, Any]) -> dict[str, Any]:
    keep = ("stamp_ns", "log_ns", "topic", "frame_id")
    return {k: origin[k] for k in keep if origin.get(k) is not None}


# ------------------------------------------------------------------------------------ reading
@dataclass
class PayloadSource:
    """Payloads to decode, from any of the layouts: a header (``None`` for a lone ``.lwb`` with
    nothing beside it), the index and a way to read each payload's bytes."""

    path: Path
    kind: str  # "stream file" | "payload folder" | "payload file"
    header: StreamHeader | None
    entries: list[FrameEntry]
    sensor_file: Path | None = None  # a plain sensor.json that stands in for the header's tables

    def read(self, i: int) -> bytes:
        e = self.entries[i]
        if self.kind == "stream file":
            with open(self.path, "rb") as fh:
                fh.seek(e.offset - _LEN.size)
                (n,) = _LEN.unpack(fh.read(_LEN.size))
                data = fh.read(e.bytes)
            if n != e.bytes or len(data) != e.bytes:
                raise DataFormatError(f"{self.path}: frame {e.name}: the index and the record disagree on its length")
            return data
        folder = self.path if self.kind == "payload folder" else self.path.parent
        file = folder / (e.file or "")
        if not file.is_file():
            raise DataFormatError(f"{self.path}: frame {e.name}: payload file {file.name} is missing")
        return file.read_bytes()

    def __iter__(self) -> Iterator[tuple[FrameEntry, bytes]]:
        for i, e in enumerate(self.entries):
            yield e, self.read(i)

    def sensors(self) -> list[SensorModel]:
        """Every sensor this source's payloads may name (the stream header's tables and a
        ``sensor.json`` beside the payloads): what a decoder of them is handed."""
        models = self.header.sensor_models(str(self.path)) if self.header is not None else []
        if self.sensor_file is not None:
            from lwbench.io import read_sensor_file

            models.append(read_sensor_file(self.sensor_file))
        return models


def is_stream_file(path: Path) -> bool:
    """Whether ``path`` starts like an ``.lwbs`` stream file (reads 4 bytes)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(4) == MAGIC
    except OSError:
        return False


def _load_json(blob: bytes, where: str) -> Any:
    try:
        return json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{where}: not valid JSON ({exc})") from None


def _read_stream_file(path: Path) -> PayloadSource:
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(_HEAD.size)
        if len(head) < _HEAD.size:
            raise DataFormatError(f"{path}: truncated stream file ({size} bytes)")
        magic, version, hlen = _HEAD.unpack(head)
        if magic != MAGIC:
            raise DataFormatError(f"{path}: not an lwbench stream file (magic {magic!r})")
        if version != FORMAT_VERSION:
            raise DataFormatError(f"{path}: stream file version {version} (this lwbench reads {FORMAT_VERSION})")
        data_start = _HEAD.size + hlen + _LEN.size
        if hlen > _MAX_JSON or data_start + _FOOT.size > size:
            raise DataFormatError(f"{path}: truncated stream file (header of {hlen} bytes in a {size}-byte file)")
        blob = fh.read(hlen)
        (crc,) = _LEN.unpack(fh.read(_LEN.size))
        if zlib.crc32(blob) != crc:
            raise DataFormatError(f"{path}: stream header checksum mismatch (corrupted file)")
        header = StreamHeader.from_dict(_load_json(blob, f"{path} header"), str(path))
        fh.seek(size - _FOOT.size)
        offset, ilen, icrc, end = _FOOT.unpack(fh.read(_FOOT.size))
        if end != END_MAGIC:
            raise DataFormatError(
                f"{path}: the stream file has no index at its end (cut short while it was written?)"
            )
        if ilen > _MAX_JSON or offset < data_start or offset + ilen != size - _FOOT.size:
            raise DataFormatError(f"{path}: the stream index's position does not fit the file")
        fh.seek(offset)
        iblob = fh.read(ilen)
    if zlib.crc32(iblob) != icrc:
        raise DataFormatError(f"{path}: stream index checksum mismatch (corrupted file)")
    index = _load_json(iblob, f"{path} index")
    frames = index.get("frames") if isinstance(index, dict) else None
    if not isinstance(frames, list):
        raise DataFormatError(f"{path}: the stream index has no frame list")
    late = index.get("sensors", {})
    if not isinstance(late, dict):
        raise DataFormatError(f"{path}: the stream index's sensors must be a JSON object")
    header.sensors = {**late, **header.sensors}
    entries = [FrameEntry.from_dict(d, str(path)) for d in frames]
    for e in entries:
        if e.offset is None or e.offset < data_start + _LEN.size or e.offset + e.bytes > offset:
            raise DataFormatError(f"{path}: frame {e.name}: its payload lies outside the file's data section")
    return PayloadSource(path, "stream file", header, entries)


def _read_stream_json(folder: Path) -> tuple[StreamHeader, list[FrameEntry]]:
    file = folder / STREAM_JSON
    try:
        doc = _load_json(file.read_bytes(), str(file))
    except OSError as exc:
        raise DataFormatError(f"{file}: cannot read ({exc})") from None
    header = StreamHeader.from_dict(doc, str(file))
    frames = doc.get("frames", [])
    if not isinstance(frames, list):
        raise DataFormatError(f"{file}: 'frames' must be a list")
    return header, [FrameEntry.from_dict(d, str(file)) for d in frames]


def _lone_payload(path: Path) -> PayloadSource:
    """A single ``.lwb``: its stream's header and index entry if ``stream.json`` lies beside it,
    else just the file (with a ``sensor.json`` beside it, if there is one)."""
    from lwbench.io import SENSOR_FILE

    entry = FrameEntry(0, path.name.removesuffix(PAYLOAD_SUFFIX), path.stat().st_size, file=path.name)
    if (path.parent / STREAM_JSON).is_file():
        header, entries = _read_stream_json(path.parent)
        mine = [e for e in entries if e.file == path.name]
        return PayloadSource(path, "payload file", header, mine or [entry])
    sensor = path.parent / SENSOR_FILE
    return PayloadSource(path, "payload file", None, [entry], sensor if sensor.is_file() else None)


def open_payloads(path: str | Path) -> PayloadSource:
    """Payloads at ``path``: a ``.lwbs`` stream file, a folder written by ``lwbench encode``
    (``stream.json`` + ``.lwb`` files, or ``.lwb`` files alone) or one ``.lwb`` file."""
    from lwbench.payload import MAGIC as PAYLOAD_MAGIC

    path = Path(path)
    if path.is_dir():
        if (path / STREAM_JSON).is_file():
            header, entries = _read_stream_json(path)
            return PayloadSource(path, "payload folder", header, entries)
        files = sorted(p for p in path.iterdir() if p.suffix == PAYLOAD_SUFFIX and p.is_file())
        if not files:
            raise DataFormatError(f"{path}: no {PAYLOAD_SUFFIX} payloads and no {STREAM_JSON} in this folder")
        from lwbench.io import SENSOR_FILE

        entries = [FrameEntry(i, p.stem, p.stat().st_size, file=p.name) for i, p in enumerate(files)]
        sensor = path / SENSOR_FILE
        return PayloadSource(path, "payload folder", None, entries, sensor if sensor.is_file() else None)
    if not path.is_file():
        raise DataFormatError(f"{path} does not exist")
    if is_stream_file(path):
        return _read_stream_file(path)
    with open(path, "rb") as fh:
        if fh.read(4) == PAYLOAD_MAGIC:
            return _lone_payload(path)
    raise DataFormatError(f"{path}: neither an lwbench stream file ({STREAM_SUFFIX}) nor a payload ({PAYLOAD_SUFFIX})")
