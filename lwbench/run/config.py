"""Run files: a whole study -- datasets x codecs x parameter grids x seeds -- in one TOML file a
team commits, so a published rate-distortion figure is one command (``lwbench run --config``).

::

    store = "lwbench-results/rd.sqlite"   # optional; --store on the command line wins
    frames = 10                            # optional: first N frames of every dataset
    seeds = [0, 1, 2]                      # optional, default [0]
    sequence_metrics = true                # optional
    metrics = ["kiss"]                     # optional: opt-in sequence metrics to run as well
    workers = 1                            # optional
    timeout = 600                          # optional: seconds per evaluation (0: no limit; default
                                           # 3600); --timeout on the command line wins

    [[dataset]]
    name = "sim"                           # a registered name or a path
    params = { scene = "tunnel" }
    frames = 5                             # optional: this dataset's first N frames
    metric_params = { floor = { sigma = 0.01 } }   # optional: over [metric_params], this dataset only

    [[dataset]]
    name = "${LWBENCH_REAL}/kitti00_frames0-1"     # ${VAR}: an environment variable
    params = { sensor = "hdl64e" }

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

A dataset's ``name`` and its string ``params`` may name environment variables as ``${VAR}`` (only
the braced form): data a user keeps elsewhere, e.g. ``${LWBENCH_REAL}`` for the folder of real
samples. A variable that is not set (or is empty) is an error that names it and the file, as
bash's ``${VAR:?}``. A relative path -- written out or after expansion -- is relative to the
current directory, not to the run file. A dataset's ``metric_params`` are merged key by key over
the top-level ``[metric_params]`` for that dataset's plans only (and checked the same way, when
the request is planned).

Every key is checked: an unknown one is an error that lists the known ones.
"""

from __future__ import annotations

import math
import os
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lwbench.errors import ParameterError

from .execute import DEFAULT_TIMEOUT_S
from .request import DatasetRequest, RunRequest

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["read_run_file"]

_TOP = {"store", "frames", "seeds", "sequence_metrics", "metrics", "workers", "timeout", "dataset", "codec",
        "metric_params"}
_DATASET = {"name", "params", "frames", "metric_params"}
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


def _timeout(value: Any, path: Path) -> float | None:
    """The file's ``timeout`` as :attr:`RunRequest.timeout_s` (0: no limit, as ``--timeout 0``)."""
    if value is None:
        return DEFAULT_TIMEOUT_S
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise ParameterError(f"{path}: timeout must be seconds per evaluation, a number >= 0 (0: no limit), "
                             f"got {value!r}")
    return float(value) or None


def _table(value: Any, path: Path, where: str) -> dict:
    if not isinstance(value, dict):
        raise ParameterError(f"{path}: {where} must be a table, e.g. {{ key = value }}, got {value!r}")
    return dict(value)


def _metric_params(value: Any, path: Path, where: str) -> dict[str, dict[str, Any]]:
    """METRIC -> {KEY: VALUE} (the metrics and their keys are checked when the request is planned)."""
    table = _table(value, path, where)
    for metric, given in table.items():
        if not isinstance(given, dict):
            raise ParameterError(f"{path}: {where}: {metric} must be a table of its settings, "
                                 f"e.g. {metric} = {{ key = value }}, got {given!r}")
    return {metric: dict(given) for metric, given in table.items()}


_VARIABLE = re.compile(r"\$\{([^}]*)\}")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _expand(text: str, path: Path, where: str) -> str:
    """``${VAR}`` -> its value in the environment; unset, empty or malformed: an error."""
    if "${" in _VARIABLE.sub("", text):
        raise ParameterError(f"{path}: {where} {text!r} has a '${{' with no closing '}}'")

    def value(match: re.Match[str]) -> str:
        name = match.group(1)
        if not _NAME.fullmatch(name):
            raise ParameterError(f"{path}: {where} {text!r}: {match.group(0)} does not name an environment variable")
        if not os.environ.get(name):
            raise ParameterError(f"{path}: {where} {text!r} needs the environment variable {name}, which is not "
                                 f"set: set it (e.g. export {name}=...) and run again")
        return os.environ[name]

    return _VARIABLE.sub(value, text)


def _dataset(table: Mapping[str, Any], i: int, path: Path) -> DatasetRequest:
    where = f"[[dataset]] {i + 1}"
    name = _expand(str(table["name"]), path, f"{where} name")
    params = {k: _expand(v, path, f"{where} params.{k}") if isinstance(v, str) else v
              for k, v in _table(table.get("params", {}), path, f"{where} params").items()}
    return DatasetRequest(name, params, _frames(table.get("frames"), path),
                          _metric_params(table.get("metric_params", {}), path, f"{where} metric_params"))


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
        datasets=tuple(_dataset(d, i, path) for i, d in enumerate(datasets)),
        codecs=tuple(sweeps),
        sweeps=sweeps,
        frames=doc.get("frames"),
        seeds=tuple(int(s) for s in _as_list(doc.get("seeds", [0]))),
        metric_params=_metric_params(doc.get("metric_params", {}), path, "[metric_params]"),
        sequence_metrics=bool(doc.get("sequence_metrics", True)),
        metrics=tuple(str(m) for m in _as_list(doc.get("metrics", []))),
        store=Path(store) if store else None,
        workers=int(doc.get("workers", 1)),
        timeout_s=_timeout(doc.get("timeout"), path),
    )
