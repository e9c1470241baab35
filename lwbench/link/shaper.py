"""The link model: a bandwidth cap (token bucket) with optional packet loss, delay and corruption.

It stands where ``tc`` would on the scout's network interface (an egress qdisc): payloads are cut
into packets of ``mtu`` bytes, each waits for tokens (``rate`` bytes per second, at most ``burst``
saved up), then leaves after ``delay``. With ``loss`` each packet is lost with that probability
and a frame missing a packet is lost whole (best-effort UDP, as ROS 2's sensor-data QoS: a
fragmented message with a hole is dropped) -- but its packets used the link all the same.
With ``corrupt`` a frame has one bit of its payload flipped on the wire. Every random choice
comes from one generator seeded by ``seed``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from lwbench.errors import ParameterError

__all__ = ["KB", "LinkModel", "TokenBucket", "parse_cap"]

KB = 1000  # bytes: link rates are in SI kilobytes per second, as network tools print them


@dataclass(frozen=True)
class LinkModel:
    """What the link between scout and base does to the bytes (see the module docstring)."""

    rate_kbps: float | None = None  # None: no cap
    burst: int | None = None  # bytes; default: 100 ms of rate, at least one packet
    loss: float = 0.0
    delay_ms: float = 0.0
    corrupt: float = 0.0
    mtu: int = 1400
    seed: int = 0

    def __post_init__(self) -> None:
        if self.rate_kbps is not None and not self.rate_kbps > 0:
            raise ParameterError(f"link rate must be positive (KB/s), got {self.rate_kbps}")
        for name in ("loss", "corrupt"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ParameterError(f"--{name} is a probability in [0, 1), got {getattr(self, name)}")
        if self.delay_ms < 0 or self.mtu < 64 or (self.burst is not None and self.burst < self.mtu):
            raise ParameterError("need delay >= 0, mtu >= 64 and burst >= mtu")

    @property
    def rate(self) -> float | None:
        """Bytes per second, or None."""
        return None if self.rate_kbps is None else self.rate_kbps * KB

    @property
    def bucket(self) -> int:
        if self.burst is not None:
            return self.burst
        # tc-tbf's own example shapes 0.5 mbit/s with a 5 kB bucket (80 ms of its rate).
        return self.mtu if self.rate is None else max(self.mtu, int(self.rate * 0.1))

    @property
    def label(self) -> str:
        cap = "uncapped" if self.rate_kbps is None else f"{self.rate_kbps:g} KB/s"
        extras = [f"loss {self.loss:g}" if self.loss else "", f"delay {self.delay_ms:g} ms" if self.delay_ms else "",
                  f"corrupt {self.corrupt:g}" if self.corrupt else ""]
        return ", ".join([cap, *[e for e in extras if e]])

    def rng(self) -> np.random.Generator:
        return np.random.default_rng([self.seed, 0x11C])

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> LinkModel:
        return cls(**d)


def parse_cap(text: str) -> float | None:
    """A ``--cap`` word: KB/s, or ``none`` / ``0`` for no cap."""
    t = text.strip().lower()
    if t in ("none", "0", "inf", "uncapped"):
        return None
    try:
        value = float(t)
    except ValueError:
        raise ParameterError(f"--cap takes KB/s (a number) or none, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise ParameterError(f"--cap must be a positive number of KB/s (or none), got {text!r}")
    return value


class TokenBucket:
    """``rate`` bytes per second, at most ``burst`` bytes saved up; :meth:`take` blocks until
    ``n`` (<= burst) bytes may go. ``clock`` and ``sleep`` are injectable for tests."""

    def __init__(self, rate: float | None, burst: int, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.rate, self.burst = rate, burst
        self.clock, self.sleep = clock, sleep
        self.tokens = float(burst)
        self.last = clock()

    def take(self, n: int) -> float:
        """Wait for ``n`` tokens and spend them; returns the time they were granted."""
        if self.rate is None:
            return self.clock()
        if n > self.burst:
            raise ValueError(f"{n} bytes exceed the bucket ({self.burst} bytes)")
        while True:
            now = self.clock()
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
            self.last = now
            if self.tokens >= n - 1e-6:  # (a sleep of the exact deficit can fall short by a rounding)
                self.tokens -= n
                return now
            self.sleep(max((n - self.tokens) / self.rate, 1e-6))
