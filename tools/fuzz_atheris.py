"""Coverage-guided fuzzing of one codec's decoder with atheris (libFuzzer), where it installs.

    python tools/fuzz_atheris.py CODEC [libFuzzer flags]
    python tools/fuzz_atheris.py rangeimage -atheris_runs=20000 -timeout=10 -rss_limit_mb=3072

libFuzzer's bytes drive :func:`lwbench.fuzz.mutate` (the same structure-aware mutations as the
hypothesis tests and ``lwbench fuzz``) over the codec's seed payloads, and the decode runs
in this process: any exception but ``PayloadError`` is a crash that libFuzzer saves as a
reproducer; ``-timeout`` and ``-rss_limit_mb`` catch hangs and memory bombs.
"""

from __future__ import annotations

import sys

if "-h" in sys.argv[1:] or "--help" in sys.argv[1:]:
    print(__doc__)
    sys.exit(0)
try:
    import atheris
except ImportError:
    sys.exit("tools/fuzz_atheris.py needs atheris (pip install atheris; not a dependency of lwbench)\n" + __doc__)

with atheris.instrument_imports():
    import lwbench  # noqa: F401
    from lwbench import PayloadError, codec_class
    from lwbench.fuzz import mutate, seed_payloads, split_payload


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
    cls = codec_class(name)
    seeds = seed_payloads(cls, cls.test_params())
    bodies = [split_payload(data).body for _, data in seeds]

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
