"""Plugin discovery: entry points in the ``lwbench`` group, loaded one at a time.

pluggy's own ``load_setuptools_entrypoints`` stops at the first plugin that fails to import,
so one broken third-party package would take the whole tool down. Here each entry point is
loaded and registered on its own; a failure is recorded (and shown by ``lwbench list``) and the
rest carry on. ``strict=True`` (CLI ``--strict``, for CI) turns any failure into an error.

``LWBENCH_PLUGINS`` (comma-separated import names) registers modules that are not installed
packages -- a plugin being written, a test's misbehaving codec -- the same way. A registry
knows how it was built (:meth:`Registry.recipe`), so that worker processes, which must load the
same plugins, rebuild it from entry points and module names.
"""

from __future__ import annotations

import importlib
import importlib.metadata as md
import os
import traceback
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import pluggy

from lwbench import hookspecs
from lwbench.codec import Codec
from lwbench.dataset import Dataset
from lwbench.errors import PluginError
from lwbench.metric import FrameMetric, MetricId, SequenceMetric, as_metric_id

__all__ = ["Registry", "PluginFailure", "PluginError", "get_registry", "registry_from_recipe", "ENTRY_POINT_GROUP",
           "PLUGINS_ENV"]

ENTRY_POINT_GROUP = "lwbench"
PLUGINS_ENV = "LWBENCH_PLUGINS"


@dataclass(frozen=True)
class PluginFailure:
    plugin: str
    target: str
    error: str
    detail: str = ""


@dataclass
class Registry:
    """What the installed plugins provide, by name, and which package provides each."""

    pm: pluggy.PluginManager
    codecs: dict[str, type[Codec]] = field(default_factory=dict)
    datasets: dict[str, type[Dataset]] = field(default_factory=dict)
    frame_metrics: dict[str, type[FrameMetric]] = field(default_factory=dict)
    sequence_metrics: dict[str, type[SequenceMetric]] = field(default_factory=dict)
    providers: dict[tuple[str, str], str] = field(default_factory=dict)
    # "dist==version" of the package providing each thing: part of result keys, so a plugin
    # release with new code is never served its predecessor's cached numbers.
    plugin_versions: dict[tuple[str, str], str] = field(default_factory=dict)
    failures: list[PluginFailure] = field(default_factory=list)
    # How this registry was built: whether entry points were loaded, the modules registered by
    # import name, and whether anything else (an object) was registered -- which another
    # process cannot rebuild.
    entry_points: bool = False
    modules: list[str] = field(default_factory=list)
    objects: list[str] = field(default_factory=list)

    # -- loading ---------------------------------------------------------------------------
    def recipe(self) -> tuple[bool, tuple[str, ...]] | None:
        """What another process needs to build the same registry (``None`` if it cannot: a
        plugin was registered as an object, e.g. a test's ``SimpleNamespace``)."""
        return None if self.objects else (self.entry_points, tuple(self.modules))

    def register_module(self, module_name: str) -> bool:
        """Import a module by name and register it as a plugin (False, and a recorded failure,
        if it cannot be imported or registered)."""
        try:
            module = importlib.import_module(module_name)
        except Exception as exc:  # noqa: BLE001 - the plugin's error, reported like an entry point's
            self.record_failure(module_name, module_name, exc)
            return False
        version = getattr(module, "__version__", "0")
        ok = self.register(module, module_name, provider=PLUGINS_ENV, target=module_name, version=str(version),
                           _by_name=True)
        if ok:
            self.modules.append(module_name)
        return ok

    def load_env_plugins(self) -> None:
        for name in filter(None, (n.strip() for n in os.environ.get(PLUGINS_ENV, "").split(","))):
            self.register_module(name)

    def load_entry_points(self, group: str = ENTRY_POINT_GROUP) -> None:
        self.entry_points = True
        for ep in sorted(md.entry_points(group=group), key=lambda e: e.name):
            dist = ep.dist.name if ep.dist is not None else "?"
            version = ep.dist.version if ep.dist is not None else "?"
            try:
                module = ep.load()
            except Exception as exc:  # noqa: BLE001 - any import error is the plugin's, not ours
                self.record_failure(ep.name, ep.value, exc)
                continue
            self.register(module, ep.name, provider=dist, target=ep.value, version=version, _by_name=True)

    def register(
        self, plugin: Any, name: str, *, provider: str = "?", target: str = "", version: str = "?",
        _by_name: bool = False,
    ) -> bool:
        """Register one plugin object and collect what it provides; False if it failed."""
        if not _by_name and provider == "?":
            self.objects.append(name)
        try:
            self.pm.register(plugin, name=name)
            self.pm.check_pending()
        except Exception as exc:  # noqa: BLE001
            if self.pm.is_registered(plugin):
                self.pm.unregister(plugin)
            self.record_failure(name, target or repr(plugin), exc)
            return False
        try:
            self._collect(plugin, name, provider, version)
        except Exception as exc:  # noqa: BLE001
            self.pm.unregister(plugin)
            self.record_failure(name, target or repr(plugin), exc)
            return False
        return True

    def _collect(self, plugin: Any, name: str, provider: str, version: str) -> None:
        def call(hook: str) -> list:
            impl = getattr(plugin, hook, None)
            return list(impl() or []) if impl is not None else []

        found: list[tuple[str, dict, str, type]] = []
        for cls in call("lwbench_codecs"):
            _check_subclass(cls, Codec, "codec")
            found.append(("codec", self.codecs, cls.name, cls))
        for cls in call("lwbench_datasets"):
            _check_subclass(cls, Dataset, "dataset")
            found.append(("dataset", self.datasets, cls.name, cls))
        for cls in call("lwbench_metrics"):
            if isinstance(cls, type) and issubclass(cls, FrameMetric):
                found.append(("metric", self.frame_metrics, cls.name, cls))
            elif isinstance(cls, type) and issubclass(cls, SequenceMetric):
                found.append(("metric", self.sequence_metrics, cls.name, cls))
            else:
                raise PluginError(f"{cls!r} is not a FrameMetric or SequenceMetric subclass")
        taken_ids = {i for m in (*self.frame_metrics.values(), *self.sequence_metrics.values()) for i in m.ids}
        for kind, table, key, cls in found:
            if key in table:
                raise PluginError(f"{kind} {key!r} is already provided by {self.providers[(kind, key)]}")
            if kind == "metric":
                clash = taken_ids & set(cls.ids)
                if clash:
                    raise PluginError(f"metric {key!r} redefines metric id(s) {sorted(clash)}")
                taken_ids |= set(cls.ids)
        for kind, table, key, cls in found:
            table[key] = cls
            self.providers[(kind, key)] = f"{provider} ({name})"
            self.plugin_versions[(kind, key)] = f"{provider}=={version}"

    def record_failure(self, name: str, target: str, exc: BaseException) -> None:
        """Record that plugin ``name`` failed (``target``: what was being loaded); `lwbench list` shows it."""
        detail = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.failures.append(PluginFailure(name, target, f"{type(exc).__name__}: {exc}", detail))

    # -- lookup ----------------------------------------------------------------------------
    def codec(self, name: str) -> type[Codec]:
        return _lookup(self.codecs, name, "codec", self.failures)

    def dataset(self, name: str) -> type[Dataset]:
        return _lookup(self.datasets, name, "dataset", self.failures)

    def plugin_version(self, kind: str, name: str) -> str:
        return self.plugin_versions.get((kind, name), "?")

    def frame_metric_instances(self, metric_params: dict[str, dict] | None = None) -> list[FrameMetric]:
        """Every frame metric, configured; ``metric_params`` maps metric name -> parameters."""
        return _instances(self.frame_metrics, metric_params or {})

    def sequence_metric_instances(
        self, metric_params: dict[str, dict] | None = None, named: Sequence[str] = ()
    ) -> list[SequenceMetric]:
        """The sequence metrics a run computes, configured: those that declare ``in_default_run``
        and the opt-in ones ``named`` (checked by :meth:`check_named_metrics`)."""
        wanted = self.check_named_metrics(named)
        chosen = {n: c for n, c in self.sequence_metrics.items() if c.in_default_run or n in wanted}
        return _instances(chosen, metric_params or {})

    def check_named_metrics(self, named: Sequence[str]) -> set[str]:
        """The metric names a run asked for by name (``--metric``); an unknown name is an error.
        Frame metrics always run, and so do default sequence metrics: naming them changes nothing."""
        known = {**self.frame_metrics, **self.sequence_metrics}
        unknown = sorted(set(named) - set(known))
        if unknown:
            raise PluginError(
                f"--metric names unknown metric(s) {', '.join(unknown)}; metrics: {', '.join(sorted(known))}"
            )
        return set(named)

    def check_metric_params(self, metric_params: dict[str, dict]) -> None:
        """Reject parameters for metrics that are not installed (values are checked on use)."""
        known = {**self.frame_metrics, **self.sequence_metrics}
        unknown = sorted(set(metric_params) - set(known))
        if unknown:
            raise PluginError(
                f"--metric-param for unknown metric(s) {', '.join(unknown)}; metrics: {', '.join(sorted(known))}"
            )
        for name, given in metric_params.items():
            known[name](**given)

    def metric_info(self) -> dict[str, MetricId]:
        """Every metric id with its unit and direction, in leaderboard order (by each metric's
        ``order``, then as declared)."""
        metrics = sorted(
            (*self.frame_metrics.values(), *self.sequence_metrics.values()), key=lambda m: (m.order, m.name)
        )
        return {str(i): as_metric_id(i) for m in metrics for i in m.ids}

    def metric_declarations(self) -> list[dict]:
        """Each installed metric's declaration (``describe()`` and ``order``): what a store keeps
        so that its board reads the same where a metric plugin is missing."""
        return [m.declaration() for m in (*self.frame_metrics.values(), *self.sequence_metrics.values())]

    def default_columns(self) -> tuple[str, ...]:
        return tuple(i for i, info in self.metric_info().items() if info.default)

    def metric_ids(self) -> list[str]:
        ids: list[str] = []
        for m in self.frame_metrics.values():
            ids.extend(m.ids)
        return ids

    def raise_failures(self) -> None:
        if self.failures:
            lines = "\n".join(f"  {f.plugin} ({f.target}): {f.error}" for f in self.failures)
            raise PluginError(f"{len(self.failures)} plugin(s) failed to load:\n{lines}")


def _instances(table: dict[str, type], metric_params: dict[str, dict]) -> list:
    return [cls(**metric_params.get(name, {})) for name, cls in sorted(table.items())]


def _check_subclass(cls: Any, base: type, what: str) -> None:
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise PluginError(f"{cls!r} is not a {base.__name__} subclass")
    if not getattr(cls, "name", None):
        raise PluginError(f"{what} class {cls.__name__} has no name")


def _lookup(table: dict, name: str, what: str, failures: list[PluginFailure]) -> Any:
    try:
        return table[name]
    except KeyError:
        hint = ""
        broken = [f.plugin for f in failures if f.plugin == name]
        if broken:
            hint = f" (plugin {name!r} failed to load: see `lwbench list`)"
        known = ", ".join(sorted(table)) or "(none installed)"
        raise PluginError(f"unknown {what} {name!r}{hint}; available: {known}") from None


def new_registry(*, load: bool = True, strict: bool = False) -> Registry:
    """A registry of the installed plugins (entry points, then ``LWBENCH_PLUGINS``)."""
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    reg = Registry(pm)
    if load:
        reg.load_entry_points()
        reg.load_env_plugins()
    if strict:
        reg.raise_failures()
    return reg


def registry_from_recipe(recipe: tuple[bool, tuple[str, ...]]) -> Registry:
    """The registry :meth:`Registry.recipe` describes, built in this process."""
    entry_points, modules = recipe
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    reg = Registry(pm)
    if entry_points:
        reg.load_entry_points()
    for name in modules:
        reg.register_module(name)
    return reg


_DEFAULT: Registry | None = None


def get_registry(*, strict: bool = False) -> Registry:
    """The process-wide registry of installed plugins (loaded once)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = new_registry()
    if strict:
        _DEFAULT.raise_failures()
    return _DEFAULT
