"""Long fuzz campaigns over every registered codec: the counts behind docs/hostile.md.

    python tools/fuzz_codecs.py [--cases 4000] [--seed 0] [--out DIR] [CODEC ...]

Each codec's seed payloads (lwbench.fuzz.seed_payloads) are mutated ``--cases`` times with a
seeded RNG and decoded in one decode server (a child process: one thread, memory ceiling,
per-case timeout). Prints a Markdown table of cases, decoded, PayloadError and other (what
broke the contract), with the worst CPU time and peak memory; with ``--out``, every failing
case is written there as a reproducible file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lwbench.fuzz import DecodeServer, fuzz_codec
from lwbench.registry import get_registry

# The learned models at sizes that keep seed encoding short; a decoder's checks do not depend
# on them (the same settings as the conformance tests).


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("codecs", nargs="*")
    ap.add_argument("--cases", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    reg = get_registry()
    names = args.codecs or sorted(reg.codecs)
    rows = []
    with DecodeServer() as server:
        for name in names:
            cls = reg.codec(name)
            r = fuzz_codec(cls, cls.test_params(), cases=args.cases, seed=args.seed, server=server)
            print(r.summary(), flush=True)
            rows.append(r)
            if args.out:
                args.out.mkdir(parents=True, exist_ok=True)
                for i, (verdict, _, case) in enumerate(r.failures):
                    (args.out / f"{name}-{i}-{verdict.replace(' ', '_')}.lwb").write_bytes(case)
    print("\n| codec | cases | decoded | PayloadError | other | max CPU s | max peak MB | wall s |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r.codec} | {r.cases} | {r.outcomes['ok']} | {r.payload_errors} | {r.other} | "
              f"{r.max_cpu_s:.2f} | {r.max_peak_mb:.0f} | {r.seconds:.0f} |")


if __name__ == "__main__":
    main()
