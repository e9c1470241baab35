"""``lwbench inspect``: what a file holds, without the user having to know its format."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError, DataWarning, LwbenchError
from lwbench.payload import MAGIC, Payload
from lwbench.registry import Registry
from lwbench.results.store import is_results_store
from lwbench.sensors.model import SensorModel

__all__ = ["describe", "is_results_store", "WHAT_INSPECT_READS"]


def _cloud_summary(points: np.ndarray) -> dict:
    if len(points) == 0:
        return {"points": 0}
    r = np.linalg.norm(points, axis=1)
    return {
        "points": int(len(points)),
        "bounds_min": np.round(points.min(axis=0), 3).tolist(),
        "bounds_max": np.round(points.max(axis=0), 3).tolist(),
        "range_m (min/median/max)": [round(float(r.min()), 3), round(float(np.median(r)), 3), round(float(r.max()), 3)],
    }


WHAT_INSPECT_READS = (
    "lwbench inspect reads lwbench payloads (.lwb), stream files (.lwbs) and payload folders, lwbench results "
    "stores, scan files (.bin, .pcd.bin, .pcd, .ply, .xyz), ROS bags (.db3, .mcap, .bag, rosbag2 folders) and "
    "dataset folders (KITTI layout, folders of scan files)"
)


def describe(path: Path, registry: Registry) -> dict:
    """What ``path`` holds, read without writing a byte (a store is opened read-only)."""
    from lwbench.streamfile import MAGIC as STREAM_MAGIC
    from lwbench.streamfile import PAYLOAD_SUFFIX, STREAM_JSON, open_payloads

    sqlite = False
    if path.is_file():
        with open(path, "rb") as fh:
            head = fh.read(16)
        if head.startswith(MAGIC):
            return _describe_payload(path, registry)
        if head.startswith(STREAM_MAGIC):
            from lwbench.transcode import describe_source

            return describe_source(registry, open_payloads(path))
        sqlite = head.startswith(b"SQLite format 3")
        if sqlite and is_results_store(path):
            return _describe_store(path)
    elif path.is_dir() and ((path / STREAM_JSON).is_file() or any(path.glob(f"*{PAYLOAD_SUFFIX}"))):
        from lwbench.transcode import describe_source

        return describe_source(registry, open_payloads(path))
    not_store = (f"{path}: an SQLite database, but not an lwbench results store (no results/meta tables of "
                 "lwbench's schema)")
    for name, cls in registry.datasets.items():
        if cls.sniff(path):
            if not sqlite:
                return _describe_dataset(path, name, cls)
            try:
                return _describe_dataset(path, name, cls)
            except LwbenchError as exc:
                why = f"{not_store}, nor a bag the {name} loader reads ({exc}); {WHAT_INSPECT_READS}"
                raise DataFormatError(why) from None
    if sqlite:
        raise DataFormatError(f"{not_store}, nor a ROS 2 bag; {WHAT_INSPECT_READS}")
    raise DataFormatError(f"{path}: not something lwbench can read; {WHAT_INSPECT_READS}")


def _sensor_summary(sensor: SensorModel) -> dict:
    compact = sensor.to_dict()
    if "preset" in compact:
        return compact
    return {
        "name": sensor.name,
        "beams": sensor.n_beams,
        "elevations_deg": [round(e, 3) for e in sensor.elevations_deg],
        "azimuth_step_deg": round(sensor.azimuth_step_deg, 5),
        "columns": sensor.n_azimuth,
        "range_m": [sensor.min_range, sensor.max_range],
        "rate_hz": sensor.rate_hz,
    }


def _describe_dataset(path: Path, name: str, cls) -> dict:
    # The loaders' DataWarnings (skipped files, a guessed beam table) belong in the report.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DataWarning)
        ds = cls(path=str(path))
        frame = ds[0]
    info: dict = {
        "kind": f"scan data ({name} loader)",
        "frames": len(ds),
        "poses": ds.has_poses,
        "sensor": _sensor_summary(frame.sensor),
        "fields": [f for f in ("intensity", "ring", "time") if getattr(frame, f) is not None],
    }
    source = ds.source_info() if hasattr(ds, "source_info") else {}
    info.update(source)
    shown = set(source.get("derived sensor", {}).get("warnings", []))
    notes = []
    for w in caught:
        if issubclass(w.category, DataWarning):
            if str(w.message) not in shown:
                notes.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if notes:
        info["warnings"] = notes
    info.update({f"first frame {k}": v for k, v in _cloud_summary(frame.points).items()})
    return info


def _describe_payload(path: Path, registry: Registry) -> dict:
    """A ``.lwb``: decoded with its stream's header (``stream.json``) or ``sensor.json`` beside it,
    when there is one, so a payload naming a derived sensor by id decodes here too."""
    from lwbench.streamfile import open_payloads

    data = path.read_bytes()
    payload = Payload.from_bytes(data)
    params: dict = {}
    sensors: list = []
    try:
        source = open_payloads(path)
        sensors = source.sensors()
        if source.header is not None and source.header.codec == payload.codec_id:
            params = dict(source.header.params)
    except LwbenchError:
        pass  # what lies beside the payload is not needed to describe it
    info: dict = {
        "kind": "lwbench payload",
        "bytes": len(data),
        "codec": payload.codec_id,
        "metadata": payload.meta,
        "body bytes": len(payload.body),
        "header+checksum bytes": len(data) - len(payload.body),
        "pose (translation)": None if payload.pose is None else np.round(payload.pose[:3, 3], 4).tolist(),
    }
    cls = registry.codecs.get(payload.codec_id)
    if cls is None:
        info["decoded"] = f"codec {payload.codec_id!r} is not installed"
        return info
    try:
        points = cls(**params).use_sensors(sensors).decode(data)
        info.update({f"decoded {k}": v for k, v in _cloud_summary(np.asarray(points)).items()})
    except Exception as exc:  # noqa: BLE001 - report, do not crash, on a payload we cannot decode
        info["decoded"] = f"failed: {type(exc).__name__}: {exc}"
    return info


def _describe_store(path: Path) -> dict:
    from lwbench.results.store import ResultStore

    with ResultStore(path, readonly=True) as store:
        conn = store.conn
        (version,) = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        rows, failed = conn.execute("SELECT COUNT(*), COALESCE(SUM(status = 'failed'), 0) FROM results").fetchone()
        datasets = [r[0] for r in conn.execute("SELECT DISTINCT dataset FROM results ORDER BY dataset")]
        codecs = [r[0] for r in conn.execute("SELECT DISTINCT codec FROM results ORDER BY codec")]
    return {
        "kind": "lwbench results store (SQLite)",
        "schema version": version,
        "rows": rows,
        "failed rows": failed,
        "datasets": datasets,
        "codecs": codecs,
    }
