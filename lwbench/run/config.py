"""Run files: a whole study -- datasets x codecs x parameter grids x seeds -- in one TOML file a
team commits, so a published rate-distortion figure is one command (``lwbench run --config``).

::

    store = "lwbench-results/rd.sqlite"   # optional; --store on the command line wins
    frames = 10                            # optional: first N frames of every dataset
    seeds = [0, 1, 2]                      # optional, default [0]
    sequence_metrics = true                # optional
    workers = 1                            # optional

    [[dataset]]
    name = "sim"                           # a registered name or a path
    params = { scene = "tunnel" }

    [[codec]]
    name = "draco"
    params = { quantization_bits = [10, 12, 14, 16] }   # a list is a sweep, a scalar one value

    [metric_params]
    geometry = { peak = 59.70 }

Every key is checked: an unknown one is an error that lists the known ones.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lwbench.errors import ParameterError
from lwbench.registry import Registry

from .plan import RunPlan, plan_run

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["RunFile", "load_run_file"]

_TOP = {"store", "frames", "seeds", "sequence_metrics", "workers", "dataset", "codec", "metric_params"}
_DATASET = {"name", "params"}
_CODEC = {"name", "params"}


@dataclass(frozen=True)
class RunFile:
    plans: tuple[RunPlan, ...]
    store: Path | None
    workers: int


def _check_keys(table: Mapping[str, Any], allowed: set[str], where: str) -> None:
    unknown = sorted(set(table) - allowed)
    if unknown:
        raise ParameterError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(allowed))}")


def _as_list(value: Any) -> list:
    return list(value) if isinstance(value, list) else [value]


def load_run_file(path: str | Path, registry: Registry) -> RunFile:
    """Every :class:`RunPlan` a run file asks for (one per dataset and seed), validated."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"run file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParameterError(f"run file {path}: {exc}") from None
    _check_keys(doc, _TOP, str(path))
    datasets = doc.get("dataset", [])
    codecs = doc.get("codec", [])
    if not datasets or not codecs:
        raise ParameterError(f"{path}: needs at least one [[dataset]] and one [[codec]] table")
    sweeps: dict[str, dict[str, list]] = {}
    for i, c in enumerate(codecs):
        _check_keys(c, _CODEC, f"{path}: [[codec]] {i + 1}")
        if "name" not in c:
            raise ParameterError(f"{path}: [[codec]] {i + 1} has no name")
        if c["name"] in sweeps:
            raise ParameterError(f"{path}: codec {c['name']!r} appears twice; give it one params grid")
        sweeps[c["name"]] = {k: _as_list(v) for k, v in c.get("params", {}).items()}
    seeds = [int(s) for s in _as_list(doc.get("seeds", [0]))]
    plans = []
    for i, d in enumerate(datasets):
        _check_keys(d, _DATASET, f"{path}: [[dataset]] {i + 1}")
        if "name" not in d:
            raise ParameterError(f"{path}: [[dataset]] {i + 1} has no name")
        for seed in seeds:
            plans.append(
                plan_run(
                    registry,
                    dataset=str(d["name"]),
                    dataset_params=d.get("params", {}),
                    codecs=list(sweeps),
                    sweeps=sweeps,
                    frames=doc.get("frames"),
                    seed=seed,
                    metric_params=doc.get("metric_params", {}),
                    sequence_metrics=bool(doc.get("sequence_metrics", True)),
                )
            )
    store = doc.get("store")
    return RunFile(tuple(plans), Path(store) if store else None, int(doc.get("workers", 1)))
