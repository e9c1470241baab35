"""Stage 1 -- plan: what a run evaluates, decided before anything is encoded.

A :class:`RunPlan` is the dataset (a registered loader and its parameters), the codec
configurations (each swept parameter's cartesian product, resolved and validated), the frames
and the run's seed. Everything that turns command-line words into that lives here, so the CLI,
the pytest gates and a Python caller plan a run the same way:

- a dataset argument is a registered name or a path; a path goes to the first installed loader
  whose ``sniff`` recognises it;
- with no codec named, the codecs that declare ``in_default_run`` are run; with no dataset
  named, the dataset that declares ``is_default`` (the simulator);
- **one seed policy**: a dataset or codec that declares a ``seed`` parameter and is not given one
  gets the run's seed, so one ``--seed`` controls every random choice of a run.

The plan's *keys* (which stored rows a run corresponds to) are computed in :mod:`.record`,
because they need the dataset's identity and the registry's versions.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lwbench.codec import Codec
from lwbench.dataset import Dataset
from lwbench.errors import DataFormatError, LwbenchError, ParameterError, PluginError
from lwbench.params import Param, config_label, resolve_params
from lwbench.registry import Registry
from lwbench.results.store import canonical_json

__all__ = [
    "CodecConfig",
    "DatasetSpec",
    "RunPlan",
    "config_label",
    "expand_codec_configs",
    "frames_for",
    "parse_assignments",
    "parse_metric_params",
    "parse_sweeps",
    "Grids",
    "plan_run",
    "preflight",
    "resolve_dataset",
]


@dataclass(frozen=True)
class DatasetSpec:
    """How to build a dataset: registry name + parameters (picklable, for worker processes)."""

    name: str
    params: dict[str, Any]

    def build(self, registry: Registry) -> Dataset:
        return registry.dataset(self.name)(**self.params)

    @property
    def label(self) -> str:
        if self.params.get("path"):
            return str(self.params["path"])
        return config_label(self.name, self.params)


@dataclass(frozen=True)
class CodecConfig:
    """One codec with fully resolved parameters: the unit a leaderboard line describes."""

    name: str
    params: dict[str, Any]

    @property
    def label(self) -> str:
        return config_label(self.name, self.params)

    @property
    def key(self) -> str:
        return f"{self.name}:{canonical_json(self.params)}"


@dataclass(frozen=True)
class RunPlan:
    """Everything a run will evaluate; built by :func:`plan_run` (or directly)."""

    dataset: DatasetSpec
    configs: tuple[CodecConfig, ...]
    frames: int | None = None
    seed: int = 0
    metric_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    sequence_metrics: bool = True
    # Opt-in metrics named for this run (``--metric``): sequence metrics that are not in the
    # default run (SequenceMetric.in_default_run = False) are computed only when named here.
    metrics: tuple[str, ...] = ()

    def frame_indices(self, dataset: Dataset) -> list[int]:
        n = len(dataset)
        return list(range(min(n, self.frames) if self.frames else n))


def _with_seed(declared: Sequence[Param], given: dict[str, Any], seed: int) -> dict[str, Any]:
    """The seed policy, in one place: a declared, ungiven ``seed`` takes the run's seed."""
    if any(p.name == "seed" for p in declared) and "seed" not in given:
        return {**given, "seed": seed}
    return given


def expand_codec_configs(codec_cls: type[Codec], values: Mapping[str, Sequence[Any]], seed: int) -> list[CodecConfig]:
    """The cartesian product of the given parameter values, each resolved and validated."""
    declared = codec_cls.all_params()
    unknown = sorted(set(values) - {p.name for p in declared})
    if unknown:
        raise ParameterError(
            f"{codec_cls.name}: unknown parameter(s) {', '.join(unknown)}; "
            f"known: {', '.join(sorted(p.name for p in declared)) or '(none)'}"
        )
    names = sorted(values)
    configs = []
    for combo in itertools.product(*(values[n] for n in names)):
        given = _with_seed(declared, dict(zip(names, combo, strict=True)), seed)
        config = CodecConfig(codec_cls.name, resolve_params(codec_cls.name, declared, given))
        lacking = codec_cls.missing(config.params)
        if lacking:
            raise ParameterError(f"{codec_cls.name}: {lacking}")
        configs.append(config)
    return _unique(configs)


#: A codec's parameter grid (key -> values, their product is run), or several whose union is.
Grids = Mapping[str, Sequence[Any]] | Sequence[Mapping[str, Sequence[Any]]]


def _unique(configs: list[CodecConfig]) -> list[CodecConfig]:
    seen, out = set(), []
    for c in configs:
        if c.key not in seen:
            seen.add(c.key)
            out.append(c)
    return out


def resolve_dataset(registry: Registry, dataset: str | None, params: Mapping[str, Any], seed: int) -> DatasetSpec:
    """A registered name, a path (auto-detected loader) or ``None`` (the default dataset)."""
    if dataset is None:
        defaults = [name for name, cls in sorted(registry.datasets.items()) if getattr(cls, "is_default", False)]
        if not defaults:
            raise PluginError("no installed dataset declares itself the default: pass --dataset NAME_OR_PATH")
        dataset = defaults[0]
    given = dict(params)
    if dataset not in registry.datasets:
        path = Path(dataset).expanduser()
        if path.exists() or "/" in dataset or path.suffix:
            if not path.exists():
                raise DataFormatError(f"dataset path {dataset} does not exist")
            for name, cls in sorted(registry.datasets.items()):
                if cls.sniff(path):
                    return DatasetSpec(name, _with_seed(cls.params, {**given, "path": str(path.resolve())}, seed))
            raise DataFormatError(
                f"no installed loader recognises {dataset}; loaders: "
                + ", ".join(f"{n} ({c.description})" for n, c in sorted(registry.datasets.items()) if c.description)
            )
    cls = registry.dataset(dataset)  # a clear error for an unknown name
    return DatasetSpec(dataset, _with_seed(cls.params, given, seed))


def parse_assignments(items: Sequence[str], what: str) -> dict[str, str]:
    """``KEY=VALUE`` words -> a dict (``ParameterError`` on anything else)."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"{what} must look like KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def parse_sweeps(
    items: Sequence[str], owners: Sequence[str], what: str = "--param", owner_kind: str = "codec"
) -> dict[str, dict[str, list[str]]]:
    """``OWNER.KEY=V1[,V2...]`` words -> {owner: {key: [values]}} for the listed owners."""
    out: dict[str, dict[str, list[str]]] = {o: {} for o in owners}
    for item in items:
        target, sep, value = item.partition("=")
        owner, dot, key = target.partition(".")
        if not sep or not dot or not key.strip():
            raise ParameterError(f"{what} must look like {owner_kind.upper()}.KEY=VALUE[,VALUE...], got {item!r}")
        owner, key = owner.strip(), key.strip()
        if owner not in out:
            raise ParameterError(
                f"{what} {item!r} is for {owner_kind} {owner!r}, which is not in this run's --{owner_kind} list "
                f"({', '.join(owners)})"
            )
        out[owner][key] = [v.strip() for v in value.split(",")]
    return out


def parse_metric_params(items: Sequence[str], registry: Registry) -> dict[str, dict[str, str]]:
    """``--metric-param METRIC.KEY=VALUE`` words (one value each: metrics are not swept)."""
    metrics = sorted({*registry.frame_metrics, *registry.sequence_metrics})
    out: dict[str, dict[str, str]] = {}
    for metric, values in parse_sweeps(items, metrics, "--metric-param", "metric").items():
        for key, vals in values.items():
            if len(vals) != 1:
                raise ParameterError(f"--metric-param {metric}.{key}: one value only (metrics are not swept)")
            out.setdefault(metric, {})[key] = vals[0]
    return out


def frames_for(registry: Registry, spec: DatasetSpec, frames: int | None) -> DatasetSpec:
    """``--frames N``, one meaning everywhere: the first N frames of the dataset. A dataset that
    generates its frames (declares a ``frames`` parameter, as the simulator) and would give fewer
    by default is asked for N -- its first frames do not depend on how many it makes -- unless
    the user set that parameter (``--dataset-param frames=M``) themselves."""
    if frames is None or "frames" in spec.params:
        return spec
    declared = next((p for p in registry.dataset(spec.name).params if p.name == "frames"), None)
    if declared is None or declared.type != "int" or not declared.default or frames <= declared.default:
        return spec
    return DatasetSpec(spec.name, {**spec.params, "frames": frames})


def plan_run(
    registry: Registry,
    *,
    dataset: str | None = None,
    dataset_params: Mapping[str, Any] | None = None,
    codecs: Sequence[str] = (),
    sweeps: Mapping[str, Grids] | None = None,
    frames: int | None = None,
    seed: int = 0,
    metric_params: Mapping[str, Mapping[str, Any]] | None = None,
    sequence_metrics: bool = True,
    metrics: Sequence[str] = (),
) -> RunPlan:
    """Turn a request into a validated :class:`RunPlan` (every error is a clear ``LwbenchError``)."""
    spec = frames_for(registry, resolve_dataset(registry, dataset, dataset_params or {}, seed), frames)
    names = list(dict.fromkeys(codecs)) or [n for n, c in sorted(registry.codecs.items()) if c.in_default_run]
    if not names:
        raise PluginError("no codec named and no installed codec is in the default run: pass --codec NAME")
    sweeps = dict(sweeps or {})
    stray = sorted(set(sweeps) - set(names))
    if stray:
        raise ParameterError(f"parameters given for codec(s) not in this run: {', '.join(stray)}")
    configs: list[CodecConfig] = []
    for name in names:
        grids = sweeps.get(name, {})
        for grid in ([grids] if isinstance(grids, Mapping) else grids):  # a union of grids: each expanded
            configs += expand_codec_configs(registry.codec(name), grid, seed)
    metric_params = {k: dict(v) for k, v in (metric_params or {}).items()}
    registry.check_metric_params(metric_params)
    named = tuple(dict.fromkeys(metrics))
    registry.check_named_metrics(named)
    if not sequence_metrics and set(named) & set(registry.sequence_metrics):
        raise ParameterError("--metric names a sequence metric but --no-sequence-metrics turns them off")
    return RunPlan(spec, tuple(_unique(configs)), frames, seed, metric_params, sequence_metrics, named)


def preflight(registry: Registry, plan: RunPlan, *, local_devices: bool = True) -> Dataset:
    """Check what can be checked before a run writes anything, and return the built dataset.

    A dataset that cannot be opened, has no frames, or whose first scan (and so its sensor
    model) cannot be read, and a device no codec could use here (``vsgp.device=cuda:7`` on a
    one-GPU machine, which failed every row later) are :class:`~lwbench.errors.LwbenchError`
    now: the CLI prints one line, exits 2 and never creates the store. ``local_devices=False``
    (a cluster executor) leaves devices to the cluster.
    """
    if local_devices:
        from lwbench.device import resolve_device

        for config in plan.configs:
            device = config.params.get("device")
            if isinstance(device, str) and device not in ("auto", "cpu"):
                try:
                    resolve_device(device)
                except ParameterError as exc:
                    raise ParameterError(f"{config.name}.device={device}: {exc}") from None
    dataset = plan.dataset.build(registry)
    indices = plan.frame_indices(dataset)
    if not indices:
        raise DataFormatError(f"dataset {plan.dataset.label} has no frames")
    try:
        dataset[indices[0]]
    except LwbenchError:
        raise
    except (ValueError, OSError) as exc:
        raise DataFormatError(f"{plan.dataset.label}: frame {indices[0]} cannot be read ({exc})") from None
    return dataset
