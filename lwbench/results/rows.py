"""A result row and its identity: what one evaluation produced, its key (the cache and the
resume rule rest on it), and the row as plain JSON values (a bundle's line)."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from typing import Any

from lwbench.errors import StoreError

__all__ = ["ResultRow", "canonical_json", "evaluation_key", "json_safe_metrics", "metrics_from_json", "result_key",
           "row_from_dict", "row_to_dict"]


def canonical_json(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def evaluation_key(
    dataset_id: str, frame: int, codec: str, codec_version: str, plugin_version: str, params: dict, seed: int
) -> str:
    """What was *encoded*: the same data through the same code and parameters gives the same
    decoded cloud, whatever it is scored with (artifacts such as decoded clouds use this)."""
    blob = canonical_json([dataset_id, frame, codec, codec_version, plugin_version, params, seed])
    return hashlib.sha256(blob.encode()).hexdigest()


def result_key(evaluation: str, kind: str, part: str, scoring: list) -> str:
    """The identity of one row: an evaluation scored by a given set of metric versions and
    parameters. Same inputs, same key, so a re-run is a cache hit; a fixed metric, a changed
    metric parameter or a new plugin release is a different key and recomputes."""
    blob = canonical_json([evaluation, kind, part, scoring])
    return hashlib.sha256(blob.encode()).hexdigest()


def json_safe_metrics(metrics: dict[str, float | None]) -> dict[str, float | str | None]:
    # JSON has no inf/NaN: infinities (lossless PSNR) are stored as strings, NaN as null.
    out: dict[str, float | str | None] = {}
    for k, v in metrics.items():
        if v is None or (isinstance(v, float) and math.isnan(v)):
            out[k] = None
        elif isinstance(v, float) and math.isinf(v):
            out[k] = "inf" if v > 0 else "-inf"
        else:
            out[k] = float(v)
    return out


def metrics_from_json(metrics: dict) -> dict[str, float | None]:
    return {k: (float(v) if isinstance(v, str) else v) for k, v in metrics.items()}


@dataclass
class ResultRow:
    kind: str
    dataset: str
    dataset_id: str
    frame: int
    codec: str
    codec_version: str
    params: dict
    status: str
    metrics: dict[str, float | None]
    seed: int
    error: str | None = None
    extra: dict = field(default_factory=dict)
    part: str = ""
    versions: dict = field(default_factory=dict)
    lwbench_version: str = ""
    machine: str = ""
    created: str = ""
    plugin_version: str = ""
    scoring: list = field(default_factory=list)
    # Whether the dataset's sensor model was a guess (derived without ring labels) when this row
    # was scored: its range metrics stand on that guessed beam table. Not part of the key (the
    # same data and code give the same guess).
    sensor_guessed: bool = False

    @property
    def evaluation(self) -> str:
        return evaluation_key(
            self.dataset_id, self.frame, self.codec, self.codec_version, self.plugin_version, self.params, self.seed
        )

    @property
    def key(self) -> str:
        return result_key(self.evaluation, self.kind, self.part, self.scoring)


def row_to_dict(row: ResultRow) -> dict:
    """A row as plain JSON values (a bundle's line); :func:`row_from_dict` reads it back, and
    the key it computes is the key the row had."""
    return {
        "key": row.key, "kind": row.kind, "dataset": row.dataset, "dataset_id": row.dataset_id, "frame": row.frame,
        "codec": row.codec, "codec_version": row.codec_version, "params": row.params, "status": row.status,
        "error": row.error, "metrics": json_safe_metrics(row.metrics), "extra": row.extra, "part": row.part,
        "seed": row.seed, "lwbench_version": row.lwbench_version, "versions": row.versions, "machine": row.machine,
        "created": row.created, "plugin_version": row.plugin_version, "scoring": row.scoring,
        "sensor_guessed": bool(row.sensor_guessed),
    }


def row_from_dict(d: dict) -> ResultRow:
    """Inverse of :func:`row_to_dict`; a row whose recomputed key differs from its stated one
    (edited, or written by a different key rule) is refused."""
    try:
        row = ResultRow(
            kind=d["kind"], dataset=d["dataset"], dataset_id=d["dataset_id"], frame=int(d["frame"]), codec=d["codec"],
            codec_version=d["codec_version"], params=dict(d["params"]), status=d["status"],
            metrics=metrics_from_json(dict(d["metrics"])), seed=int(d["seed"]), error=d.get("error"),
            extra=dict(d.get("extra", {})), part=d.get("part", ""), versions=dict(d.get("versions", {})),
            lwbench_version=d.get("lwbench_version", ""), machine=d.get("machine", ""), created=d.get("created", ""),
            plugin_version=d.get("plugin_version", ""), scoring=list(d.get("scoring", [])),
            sensor_guessed=bool(d.get("sensor_guessed", False)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise StoreError(f"a result row is malformed ({type(exc).__name__}: {exc})") from None
    if "key" in d and d["key"] != row.key:
        raise StoreError(f"a result row's key {d['key'][:12]} does not match its content: it was edited")
    return row
