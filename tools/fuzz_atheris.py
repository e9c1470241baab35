"""Coverage-guided fuzzing of one codec's decoder with atheris (libFuzzer), where it installs.

    python tools/fuzz_atheris.py CODEC [libFuzzer flags]
    python tools/fuzz_atheris.py rangeimage -atheris_runs=20000 -timeout=10 -rss_limit_mb=3072

libFuzzer's bytes drive :func:`lwbench.fuzz.mutate` (the same structure-aware mutations as the
hypothesis tests and tools/fuzz_codecs.py) over the codec's seed payloads, and the decode runs
in this process: any exception but ``PayloadError`` is a crash that libFuzzer saves as a
reproducer; ``-timeout`` and ``-rss_limit_mb`` catch hangs and memory bombs.
"""

from __future__ import annotations

import sys

import atheris

with atheris.instrument_imports():
    import lwbench  # noqa: F401
    from lwbench.fuzz import _split, mutate, seed_payloads
    from lwbench.payload import PayloadError
    from lwbench.registry import get_registry



class ProviderChooser:
    """Mutation choices from libFuzzer's data (so coverage feedback steers them)."""

    def __init__(self, fdp: atheris.FuzzedDataProvider) -> None:
        self.fdp = fdp

    def int(self, lo: int, hi: int) -> int:
        return self.fdp.ConsumeIntInRange(lo, hi)

    def bytes(self, n: int) -> bytes:
        return self.fdp.ConsumeBytes(n).ljust(n, b"\x00")


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1].startswith("-"):
        sys.exit(__doc__)
    name = sys.argv.pop(1)
    cls = get_registry().codec(name)
    seeds = seed_payloads(cls, cls.test_params())
    bodies = [_split(data).body for _, data in seeds]

    def one_input(data: bytes) -> None:
        ch = ProviderChooser(atheris.FuzzedDataProvider(data))
        variant, payload = seeds[ch.int(0, len(seeds) - 1)]
        try:
            cls(**variant).decode(mutate(payload, ch, bodies))
        except PayloadError:
            pass

    atheris.Setup(sys.argv, one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
