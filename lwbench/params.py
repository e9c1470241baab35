"""Declared parameters: how codecs, datasets and metrics say what they accept.

Declaring a parameter (type, default, range, choices, help) is what lets sweeps, the CLI,
``lwbench list`` and the result keys all agree on it without knowing the plugin.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from lwbench.errors import ParameterError

__all__ = ["Param", "config_label", "resolve_params"]


_TYPES: dict[str, type] = {"int": int, "float": float, "str": str, "bool": bool}


@dataclass(frozen=True)
class Param:
    """A parameter a codec or dataset declares, so sweeps, the CLI and ``lwbench list`` know it.

    ``type`` is one of ``int``, ``float``, ``str``, ``bool``. ``low``/``high`` bound numbers
    (inclusive); ``choices`` restricts strings. ``default=None`` means "optional, no value".
    """

    name: str
    type: str
    default: Any
    help: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if self.type not in _TYPES:
            raise ValueError(f"param {self.name}: type must be one of {sorted(_TYPES)}")

    def parse(self, text: str) -> Any:
        """Convert a command-line string to this parameter's type, then validate."""
        text = text.strip()
        if text.lower() in ("none", "null", ""):
            return self.validate(None)
        try:
            if self.type == "bool":
                if text.lower() in ("1", "true", "yes", "on"):
                    value: Any = True
                elif text.lower() in ("0", "false", "no", "off"):
                    value = False
                else:
                    raise ValueError(text)
            elif self.type == "int":
                value = int(float(text)) if float(text).is_integer() else int(text)
            else:
                value = _TYPES[self.type](text)
        except ValueError:
            raise ParameterError(f"{self.name}: cannot read {text!r} as {self.type}") from None
        return self.validate(value)

    def validate(self, value: Any) -> Any:
        if value is None:
            if self.default is None:
                return None
            raise ParameterError(f"{self.name}: a value is required")
        if self.type == "float" and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
        elif self.type == "int" and isinstance(value, float) and value.is_integer():
            value = int(value)
        expected = _TYPES[self.type]
        if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
            raise ParameterError(f"{self.name}: expected {self.type}, got {value!r}")
        if self.type in ("int", "float"):
            if isinstance(value, float) and not math.isfinite(value):
                raise ParameterError(f"{self.name}: must be finite, got {value}")
            if self.low is not None and value < self.low:
                raise ParameterError(f"{self.name}: {value} is below the minimum {self.low}")
            if self.high is not None and value > self.high:
                raise ParameterError(f"{self.name}: {value} is above the maximum {self.high}")
        if self.choices is not None and value not in self.choices:
            raise ParameterError(f"{self.name}: {value!r} is not one of {list(self.choices)}")
        return value

    def describe(self) -> dict:
        d = {"name": self.name, "type": self.type, "default": self.default, "help": self.help}
        if self.low is not None or self.high is not None:
            d["range"] = [self.low, self.high]
        if self.choices is not None:
            d["choices"] = list(self.choices)
        return d


def resolve_params(owner: str, declared: Sequence[Param], given: Mapping[str, Any]) -> dict:
    """Merge ``given`` over the declared defaults, rejecting unknown names and bad values."""
    by_name = {p.name: p for p in declared}
    unknown = sorted(set(given) - set(by_name))
    if unknown:
        known = ", ".join(sorted(by_name)) or "(none)"
        raise ParameterError(f"{owner}: unknown parameter(s) {', '.join(unknown)}; known: {known}")
    out = {}
    for p in declared:
        raw = given.get(p.name, p.default)
        out[p.name] = p.parse(raw) if isinstance(raw, str) and p.type != "str" else p.validate(raw)
    return out


def config_label(name: str, params: Mapping[str, Any]) -> str:
    """``name(k=v,...)`` over the given parameters, sorted: the one spelling of a configuration
    (leaderboards, gates and reports all use it)."""
    return f"{name}({','.join(f'{k}={v}' for k, v in sorted(params.items()))})" if params else name
