"""Run files: a whole study -- datasets x codecs x parameter grids x seeds -- in one TOML file a
team commits, so a published rate-distortion figure is one command (``lwbench run --config``).

::

    store = "lwbench-results/rd.sqlite"   # optional; --store on the command line wins
    frames = 10                            # optional: first N frames of every dataset
    seeds = [0, 1, 2]                      # optional, default [0]
    sequence_metrics = true                # optional
    metrics = ["kiss"]                     # optional: opt-in sequence metrics to run as well
    workers = 1                            # optional

    [[dataset]]
    name = "sim"                           # a registered name or a path
    params = { scene = "tunnel" }
    frames = 5                             # optional: this dataset's first N frames

    [[codec]]
    name = "draco"
    params = { quantization_bits = [10, 12, 14, 16] }   # a list is a sweep, a scalar one value

    [[codec]]                              # a codec named again: the union of its grids runs
    name = "rangeimage"
    params = { step = [0.05, 0.02, 0.01] }
    [[codec]]
    name = "rangeimage"
    params = { mode = "lossless", refine = ["beam", "none"] }

    [metric_params]
    geometry = { peak = 59.70 }

Every key is checked: an unknown one is an error that lists the known ones.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lwbench.errors import ParameterError

from .request import DatasetRequest, RunRequest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["read_run_file"]

_TOP = {"store", "frames", "seeds", "sequence_metrics", "metrics", "workers", "dataset", "codec", "metric_params"}
_DATASET = {"name", "params", "frames"}
_CODEC = {"name", "params"}


def _check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ParameterError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(allowed))}")


def _as_list(value: Any) -> list:
    return list(value) if isinstance(value, list) else [value]


def _frames(value: Any, path: Path) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ParameterError(f"{path}: a dataset's frames must be a positive integer, got {value!r}")
    return value


def _named(tables: list, what: str, allowed: set[str], path: Path) -> list[dict]:
    for i, t in enumerate(tables):
        _check_keys(t, allowed, f"{path}: [[{what}]] {i + 1}")
        if "name" not in t:
            raise ParameterError(f"{path}: [[{what}]] {i + 1} has no name")
    return tables


def read_run_file(path: str | Path) -> RunRequest:
    """The :class:`RunRequest` a run file describes (every key checked; plugins are checked
    when the request is planned)."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"run file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterError(f"run file {path} cannot be read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"run file {path}: {exc}") from None
    _check_keys(doc, _TOP, str(path))
    datasets = _named(doc.get("dataset", []), "dataset", _DATASET, path)
    codecs = _named(doc.get("codec", []), "codec", _CODEC, path)
    if not datasets or not codecs:
        raise ParameterError(f"{path}: needs at least one [[dataset]] and one [[codec]] table")
    # A codec named in several tables runs the union of their grids (scikit-learn's ParameterGrid
    # over a list of dicts): rangeimage's step swept in one, its lossless mode in another.
    sweeps: dict[str, list[dict[str, list]]] = {}
    for c in codecs:
        sweeps.setdefault(c["name"], []).append({k: _as_list(v) for k, v in c.get("params", {}).items()})
    store = doc.get("store")
    return RunRequest(
        datasets=tuple(DatasetRequest(str(d["name"]), dict(d.get("params", {})), _frames(d.get("frames"), path))
                       for d in datasets),
        codecs=tuple(sweeps),
        sweeps=sweeps,
        frames=doc.get("frames"),
        seeds=tuple(int(s) for s in _as_list(doc.get("seeds", [0]))),
        metric_params=doc.get("metric_params", {}),
        sequence_metrics=bool(doc.get("sequence_metrics", True)),
        metrics=tuple(str(m) for m in _as_list(doc.get("metrics", []))),
        store=Path(store) if store else None,
        workers=int(doc.get("workers", 1)),
    )
