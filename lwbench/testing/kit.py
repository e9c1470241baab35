"""Running the checks: per plugin (``check_codec`` ...), as ``(name, check)`` pairs, or as pytest
cases (:func:`parametrize_with_checks`, scikit-learn's pattern)."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Iterable

from .base import Check, checks_for, skip_reason

__all__ = ["check_codec", "check_dataset", "check_metric", "codec_checks", "dataset_checks", "metric_checks",
           "parametrize_with_checks"]


def plugin_kind(plugin_cls: type) -> str:
    """``codec``, ``dataset`` or ``metric``: which contract a plugin class is held to."""
    from lwbench.codec import Codec
    from lwbench.dataset import Dataset
    from lwbench.metric import FrameMetric, SequenceMetric

    for base, kind in ((Codec, "codec"), (Dataset, "dataset"), ((FrameMetric, SequenceMetric), "metric")):
        if isinstance(plugin_cls, type) and issubclass(plugin_cls, base):
            return kind
    raise TypeError(f"{plugin_cls!r} is not a lwbench Codec, Dataset or metric class")


def _skipped(reason: str) -> None:
    """A check that does not apply: a pytest skip inside pytest, nothing elsewhere."""
    pytest = sys.modules.get("pytest")
    if pytest is not None:
        pytest.skip(reason)


def _pairs(kind: str, plugin_cls: type, params: dict | None) -> list[tuple[str, Callable[[], None]]]:
    out = []
    for item in checks_for(kind):
        reason = skip_reason(item, plugin_cls)
        call = functools.partial(_skipped, reason) if reason else functools.partial(item.function, plugin_cls, params)
        out.append((item.name, call))
    return out


def codec_checks(codec_cls, params: dict | None = None) -> list[tuple[str, Callable[[], None]]]:
    """``(name, check)`` pairs, each ``check()`` raising :class:`ConformanceError` on a breach (a
    check that does not apply to what the codec declares is a pytest skip), so a test suite can
    parametrize over them: one test per check."""
    return _pairs("codec", codec_cls, params)


def dataset_checks(dataset_cls, params: dict | None = None) -> list[tuple[str, Callable[[], None]]]:
    """``(name, check)`` pairs for a dataset class with the given parameters."""
    return _pairs("dataset", dataset_cls, params)


def metric_checks(metric_cls, params: dict | None = None) -> list[tuple[str, Callable[[], None]]]:
    """``(name, check)`` pairs for a frame or sequence metric class."""
    return _pairs("metric", metric_cls, params)


def _run_all(kind: str, plugin_cls, params: dict | None) -> None:
    for item in checks_for(kind):
        if not skip_reason(item, plugin_cls):
            item.function(plugin_cls, params)


def check_codec(codec_cls, params: dict | None = None) -> None:
    """Run every contract check that applies to a codec class (raises :class:`ConformanceError`).

    Call it from a plugin's own tests -- ``check_codec(MyCodec)`` -- with ``params`` for
    settings that keep the check fast (the contract does not depend on model size)."""
    _run_all("codec", codec_cls, params)


def check_dataset(dataset_cls, params: dict | None = None) -> None:
    """Run every contract check on a dataset class (raises :class:`ConformanceError`)."""
    _run_all("dataset", dataset_cls, params)


def check_metric(metric_cls, params: dict | None = None) -> None:
    """Run every contract check on a frame or sequence metric class (raises :class:`ConformanceError`)."""
    _run_all("metric", metric_cls, params)


def parametrize_with_checks(plugins: Iterable[type | tuple[type, dict]]):
    """A ``pytest.mark.parametrize("plugin, check", ...)`` over every check of every plugin --
    codecs, datasets and metrics, each a class or ``(class, params)``::

        from lwbench.testing import parametrize_with_checks

        @parametrize_with_checks([MyCodec, (MyDataset, {"path": "tests/data"}), MyMetric])
        def test_lwbench_contract(plugin, check):
            check(plugin)

    A codec given without params runs with its :meth:`~lwbench.Codec.test_params`. One pytest
    case per (plugin, check), named ``MyCodec-check_codec_corrupt``; a check that does
    not apply to what the plugin declares (the budget check of a codec with no budget) is a skip
    that says why."""
    import pytest

    cases = []
    for item in plugins:
        plugin_cls, params = item if isinstance(item, tuple) else (item, None)
        if params is None and plugin_kind(plugin_cls) == "codec":
            params = plugin_cls.test_params() or None  # what the codec declares a quick harness runs
        for c in checks_for(plugin_kind(plugin_cls)):
            reason = skip_reason(c, plugin_cls)
            marks = [pytest.mark.skip(reason=reason)] if reason else []
            cases.append(pytest.param(plugin_cls, _bound(c, params), marks=marks,
                                      id=f"{plugin_cls.__name__}-{c.function.__name__}"))
    return pytest.mark.parametrize("plugin, check", cases)


def _bound(item: Check, params: dict | None) -> Callable[[type], None]:
    """``check(plugin_cls)`` with the plugin's parameters bound."""
    return functools.partial(_call, item.function, params)


def _call(function, params, plugin_cls) -> None:
    function(plugin_cls, params)
