"""``lwbench inspect``: what a file holds, without the user having to know its format."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lwbench.payload import MAGIC, Payload
from lwbench.registry import Registry

__all__ = ["describe"]


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


def describe(path: Path, registry: Registry) -> dict:
    if path.is_file():
        with open(path, "rb") as fh:
            head = fh.read(16)
        if head.startswith(MAGIC):
            return _describe_payload(path.read_bytes(), registry)
        if head.startswith(b"SQLite format 3"):
            return _describe_store(path)
    for name, cls in registry.datasets.items():
        if cls.sniff(path):
            ds = cls(path=str(path))
            frame = ds[0]
            info = {
                "kind": f"scan data ({name} loader)",
                "frames": len(ds),
                "poses": ds.has_poses,
                "sensor": frame.sensor.to_dict(),
                "fields": [f for f in ("intensity", "ring", "time") if getattr(frame, f) is not None],
            }
            info.update({f"first frame {k}": v for k, v in _cloud_summary(frame.points).items()})
            return info
    from lwbench.types import LwbenchError

    raise LwbenchError(f"{path}: not an lwbench payload, results store, or scan file/folder lwbench can read")


def _describe_payload(data: bytes, registry: Registry) -> dict:
    payload = Payload.from_bytes(data)
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
        codec = cls()
        points = codec.decode(data)
        info.update({f"decoded {k}": v for k, v in _cloud_summary(np.asarray(points)).items()})
    except Exception as exc:  # noqa: BLE001 - report, do not crash, on a payload we cannot decode
        info["decoded"] = f"failed: {type(exc).__name__}: {exc}"
    return info


def _describe_store(path: Path) -> dict:
    from lwbench.store import ResultStore

    with ResultStore(path, readonly=True) as store:
        rows = list(store.rows())
    return {
        "kind": "lwbench results store (SQLite)",
        "rows": len(rows),
        "failed rows": sum(r.status == "failed" for r in rows),
        "datasets": sorted({r.dataset for r in rows}),
        "codecs": sorted({r.codec for r in rows}),
    }
