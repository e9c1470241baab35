"""Fuzzing decoders: crafted payloads against a codec, decoded out of process, bounded.

The CRC catches accidents; a crafted payload (fields changed, CRC recomputed) reaches codec
code. This package makes such payloads from real ones and checks the contract every decoder
keeps (docs/design.md, "Payloads"): **only** :class:`~lwbench.PayloadError` escapes, what does
decode is a cloud a LiDAR could return (within the payload's sensor's reach, never 10 km away),
and no decode of an input of at most 1 MB takes more than a second of CPU or 512 MB of memory.

- :mod:`.mutate` -- :func:`mutate` turns a valid payload into a hostile one, re-sealed with a
  valid CRC, its choices from a :class:`Chooser` (a seeded RNG, hypothesis, atheris);
- :mod:`.server` -- :class:`DecodeServer` decodes in a sandboxed child (:mod:`lwbench.sandbox`,
  as the run's workers), measures CPU and memory per case and judges the output;
- :mod:`.campaign` -- :func:`fuzz_codec`, a whole campaign, and its :class:`FuzzReport`.
"""

from __future__ import annotations

from .campaign import FuzzReport, fuzz_codec, fuzz_frames, fuzz_sensors, parameter_variants, seed_payloads
from .mutate import MAX_CASE_BYTES, Chooser, RandomChooser, assemble, mutate, split_payload
from .server import CPU_LIMIT_S, MEMORY_LIMIT_MB, DecodeServer, Outcome, class_ref, shared_server

__all__ = [
    "CPU_LIMIT_S",
    "Chooser",
    "DecodeServer",
    "FuzzReport",
    "MAX_CASE_BYTES",
    "MEMORY_LIMIT_MB",
    "Outcome",
    "RandomChooser",
    "assemble",
    "class_ref",
    "fuzz_codec",
    "fuzz_frames",
    "fuzz_sensors",
    "mutate",
    "parameter_variants",
    "seed_payloads",
    "shared_server",
    "split_payload",
]
