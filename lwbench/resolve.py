"""What a name or a path on a command line stands for, as public functions (``lwbench.open_dataset``).

A plugin's own commands (hook ``lwbench_register_commands``) and scripts take the words a user
types -- ``--dataset ~/kitti/00 --dataset-param sensor=hdl64e`` -- and need the object lwbench
would build from them. They get it here, through the public API, instead of from the registry
and the run planner (internals that may change): the resolution is the one ``lwbench run``
uses, so a plugin command accepts exactly what every built-in command accepts. Errors are
:class:`~lwbench.errors.LwbenchError` s: raised out of a command, the CLI prints them as one line
and exits with status 2.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from lwbench.codec import Codec
from lwbench.dataset import Dataset
from lwbench.errors import PluginError
from lwbench.metric import FrameMetric, SequenceMetric

__all__ = ["codec_class", "frame_metric", "make_codec", "open_dataset", "sequence_metric"]


def open_dataset(
    source: str | Path | None = None, params: Mapping[str, Any] | Sequence[str] = (), *, seed: int = 0
) -> Dataset:
    """The dataset ``lwbench run --dataset SOURCE --dataset-param ...`` would evaluate.

    ``source`` is a registered dataset name, a path (the installed loader whose ``sniff``
    recognises it) or ``None`` (the default dataset, the simulator); ``params`` a mapping or
    ``KEY=VALUE`` words as typed after ``--dataset-param``; ``seed`` the run's seed, given to a
    dataset that declares one and is not given one."""
    from lwbench.registry import get_registry
    from lwbench.run.plan import parse_assignments, resolve_dataset

    given = dict(params) if isinstance(params, Mapping) else parse_assignments(list(params), "--dataset-param")
    registry = get_registry()
    return resolve_dataset(registry, None if source is None else str(source), given, seed).build(registry)


def codec_class(name: str) -> type[Codec]:
    """The installed codec class of that name (a clear error listing the installed ones)."""
    from lwbench.registry import get_registry

    return get_registry().codec(name)


def make_codec(name: str, params: Mapping[str, Any] | Sequence[str] = (), *, seed: int = 0) -> Codec:
    """The codec ``lwbench run --codec NAME --param NAME.KEY=VALUE`` would build: each value
    parsed and checked against the codec's declared parameters, ``seed`` given to a codec that
    declares one (a diagnostics command builds the same configuration a run scores)."""
    from lwbench.run.plan import expand_codec_configs, parse_assignments

    cls = codec_class(name)
    given = dict(params) if isinstance(params, Mapping) else parse_assignments(list(params), "--param")
    (config,) = expand_codec_configs(cls, {k: [v] for k, v in given.items()}, seed)
    return cls(**config.params)


def sequence_metric(name: str, params: Mapping[str, Any] | None = None) -> SequenceMetric:
    """The installed sequence metric of that name, configured with ``params`` (what
    ``--metric-param NAME.KEY=VALUE`` sets); a clear error when it is not installed."""
    from lwbench.registry import get_registry

    metrics = get_registry().sequence_metrics
    if name not in metrics:
        raise PluginError(f"no sequence metric {name!r} is installed (installed: {', '.join(sorted(metrics))})")
    return metrics[name](**dict(params or {}))


def frame_metric(name: str, params: Mapping[str, Any] | None = None) -> FrameMetric:
    """The installed frame metric of that name, configured with ``params``: its ``compute`` scores
    one decoded cloud against its scan (an :class:`~lwbench.Evaluation`), as a run scores it --
    a plugin command's own table uses the run's definitions; a clear error when it is not installed."""
    from lwbench.registry import get_registry

    metrics = get_registry().frame_metrics
    if name not in metrics:
        raise PluginError(f"no frame metric {name!r} is installed (installed: {', '.join(sorted(metrics))})")
    return metrics[name](**dict(params or {}))
