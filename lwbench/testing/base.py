"""What every conformance check shares: its error, its registration, and when it does not apply.

A check is a top-level function ``check_<kind>_<what>(plugin_cls, params=None)`` that raises
:class:`ConformanceError` on a breach. It is registered with the decorator :func:`check` under the
short name its old ``codec_checks`` pair had (``payloads``, ``corrupt`` ...) and a condition on what
the plugin *declares* -- its kind, its parameters, what it needs -- so that a check that does not
apply is skipped, with the reason, instead of passing without testing anything (scikit-learn's
estimator tags).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["Check", "ConformanceError", "check", "checks_for", "fail", "skip_reason"]


class ConformanceError(AssertionError):
    """A plugin breaks lwbench's contract; the message says which check and how."""


def fail(check_name: str, message: str) -> None:
    raise ConformanceError(f"{check_name}: {message}")


@dataclass(frozen=True)
class Check:
    """A registered check: the function, its short name, the plugin kind it checks, and a
    ``skip(plugin_cls)`` that returns why it does not apply (or ``""``)."""

    function: Callable[..., None]
    name: str
    kind: str  # codec | dataset | metric
    skip: Callable[[type], str]


_CHECKS: list[Check] = []


def check(name: str, kind: str, skip: Callable[[type], str] | None = None):
    """Register a check function (keeps it a plain top-level function)."""

    def register(function: Callable[..., None]) -> Callable[..., None]:
        _CHECKS.append(Check(function, name, kind, skip or (lambda cls: "")))
        return function

    return register


def checks_for(kind: str) -> list[Check]:
    return [c for c in _CHECKS if c.kind == kind]


def skip_reason(item: Check, plugin_cls: type) -> str:
    """Why ``item`` does not apply to ``plugin_cls`` (``""``: it applies)."""
    return item.skip(plugin_cls)
