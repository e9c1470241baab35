"""A fuzz campaign against vsgp's decoder (issue 23): crafted payloads (lwbench.fuzz.mutate,
CRC re-sealed), decoded out of process, counted by outcome -- and *absurd* outputs: a decoded
point farther than the payload's sensor can see (its max range) counts as a failure too.

    PYTHONPATH=tools python tools/vsgp_fuzz.py --cases 3000
    PYTHONPATH=tools:/tmp/old VSGP_FUZZ_BASE=vsgp_old python tools/vsgp_fuzz.py --cases 3000

``VSGP_FUZZ_BASE`` names the package whose ``VSGPCodec`` is fuzzed (default: the installed
plugin, ``lwbench_plugins.vsgp``; another one -- e.g. main's plugin copied to a package
``vsgp_old`` -- gives the "before" counts). Seeds: the conformance kit's fuzz frames with every
declared parameter choice (lwbench.fuzz.seed_payloads), at ``num_inducing=100`` as
tools/fuzz_codecs.py uses. A development script (not installed).
"""

from __future__ import annotations

import argparse
import importlib
import os
from collections import Counter

import numpy as np

from lwbench import LwbenchError

_BASE = importlib.import_module(os.environ.get("VSGP_FUZZ_BASE", "lwbench_plugins.vsgp")).VSGPCodec


class AbsurdOutput(LwbenchError):
    """A decode returned points beyond the payload's sensor's reach."""


class Checked(_BASE):  # type: ignore[misc,valid-type]
    """The codec under test, with the output bound checked after every decode."""

    def decode(self, data: bytes) -> np.ndarray:
        pts = super().decode(data)
        if len(pts):
            reach = self.read_sensor(self.read_payload(data)).max_range
            far = float(np.linalg.norm(pts.astype(np.float64), axis=1).max())
            if far > reach * 1.001 + 1e-3:
                raise AbsurdOutput(f"a decoded point {far:.3g} m away; the sensor reaches {reach:g} m")
        return pts


def main() -> None:
    from lwbench.fuzz import DecodeServer, fuzz_codec

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    with DecodeServer() as server:
        r = fuzz_codec(Checked, {"num_inducing": 100}, cases=args.cases, seed=args.seed, server=server)
    print(f"{os.environ.get('VSGP_FUZZ_BASE', 'lwbench_plugins.vsgp')}: {r.summary()}")
    print(f"outcomes: {dict(r.outcomes)}; verdicts: {dict(r.verdicts)}; {r.seconds:.0f} s")
    kinds = Counter(v for v, _, _ in r.failures)
    for verdict, message, case in r.failures[:10]:
        print(f"- {verdict}: {message[:160]} ({len(case)} bytes)")
    print(f"(first {len(r.failures)} failures kept: {dict(kinds)})")


if __name__ == "__main__":
    main()
