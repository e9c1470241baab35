"""Fuzzing every registered codec's decoder with hypothesis (and atheris where it installs).

Hypothesis drives :func:`lwbench.fuzz.mutate` -- crafted payloads with a valid CRC -- and the
decodes run in :class:`lwbench.fuzz.DecodeServer`'s child process, so a hang or a memory bomb
is a failed example (killed after a generous timeout, memory capped), not a hung test run. The
contract: only ``PayloadError`` escapes, within a second of CPU and 512 MB. A failure is shrunk
to a small case and printed as hex. The conformance kit's ``fuzz`` check
(test_codec_conformance.py) adds a seeded campaign per codec; ``lwbench fuzz`` runs the long
ones behind docs/hostile.md.
"""

from __future__ import annotations

import importlib.util
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_codec_conformance import FAST_PARAMS

from lwbench.fuzz import class_ref, fuzz_sensors, mutate, seed_payloads, shared_server, split_payload
from lwbench.registry import get_registry

REGISTRY = get_registry()
EXAMPLES = 30  # per codec: ~1 s each for most, a few for the learned models


class HypothesisChooser:
    """Mutation choices drawn from hypothesis, so failures shrink."""

    def __init__(self, data) -> None:
        self.data = data

    def int(self, lo: int, hi: int) -> int:
        return self.data.draw(st.integers(lo, hi))

    def bytes(self, n: int) -> bytes:
        return self.data.draw(st.binary(min_size=n, max_size=n))


@pytest.mark.heavy
@pytest.mark.parametrize("codec", sorted(REGISTRY.codecs))
def test_only_payload_errors_escape_a_decoder(codec):
    cls = REGISTRY.codec(codec)
    if cls.needs:
        pytest.skip(f"{codec} cannot encode an arbitrary scan: it needs {cls.needs} (its payload is the shared "
                    "selection payload, fuzzed through every other selector)")
    seeds = seed_payloads(cls, FAST_PARAMS.get(codec))
    assert seeds, f"{codec}: no seed payload could be encoded"
    bodies = [split_payload(data).body for _, data in seeds]
    server = shared_server()
    server.register_sensors(fuzz_sensors())

    @settings(max_examples=EXAMPLES, derandomize=True, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def check(data):
        variant, payload = data.draw(st.sampled_from(seeds))
        case = mutate(payload, HypothesisChooser(data), bodies)
        outcome = server.decode(class_ref(cls), variant, case, warm_with=payload)
        assert outcome.verdict == "fine", (
            f"{codec}: {outcome.verdict} ({outcome.kind}: {outcome.message}; {outcome.cpu_s:.2f} s, "
            f"{outcome.peak_mb:.0f} MB) on {len(case)} bytes: {case[:256].hex()}"
        )

    check()


def test_mutations_are_sealed_and_reproducible():
    from lwbench.fuzz import RandomChooser
    from lwbench.payload import PayloadError

    cls = REGISTRY.codec("raw")
    seeds = seed_payloads(cls)
    a = [mutate(d, RandomChooser(7)) for _, d in seeds]
    b = [mutate(d, RandomChooser(7)) for _, d in seeds]
    assert a == b
    # Every case passes the checksum: what stops it must be the header and codec checks.
    for case in a:
        try:
            cls().decode(case)
        except PayloadError as exc:
            assert "checksum" not in str(exc)


@pytest.mark.heavy
def test_the_harness_counts_hangs_crashes_and_bombs(tmp_path):
    """The harness itself: a decoder that hangs, dies or allocates without bound is counted as
    such (timeout, crash, memory), never as a PayloadError, and the server carries on."""
    from lwbench.fuzz import DecodeServer

    sys.path.insert(0, str(Path(__file__).parent))
    # 10 s, not less: after the hang and the crash the child is new, and the bomb's call also
    # imports the test plugin module there -- 3 s was too little once on a loaded CI machine.
    with DecodeServer(timeout_s=10.0, ceiling_mb=300) as server:
        seen = {}
        for mode in ("ok", "hang", "crash", "bomb", "slow", "far"):
            seen[mode] = server.decode("_hostile_plugins:HostileDecoder", {"mode": mode}, b"x").verdict
    assert seen == {"ok": "fine", "hang": "timeout", "crash": "crash", "bomb": "memory", "slow": "over 1 s",
                    "far": "absurd"}


def test_a_cloud_beyond_its_sensors_reach_is_absurd_and_a_decoder_refuses_it():
    """Absurd = a point farther than the payload's sensor sees (max range + 50 %), for a codec
    whose payloads name their sensor; else farther than 10 km. checked_cloud refuses the same."""
    from lwbench import MAX_COORDINATE, Payload, PayloadError, checked_cloud, get_sensor
    from lwbench.fuzz.server import judge
    from lwbench.sensors.catalog import SensorCatalog

    named = Payload("x", {"sensor": get_sensor("vlp16").to_wire()}, b"").to_bytes()  # sees to 10 m
    bare = Payload("x", {}, b"").to_bytes()
    near, far = np.array([[14.0, 0.0, 0.0]], np.float32), np.array([[16.0, 0.0, 0.0]], np.float32)
    catalog = SensorCatalog()
    assert judge(near, named, catalog, seed=named)[0] == "ok"
    assert judge(far, named, catalog, seed=named)[0] == "absurd"
    assert judge(far, named, catalog, seed=bare)[0] == "ok"  # a sensor slipped into a sensorless codec's payload
    assert judge(np.array([[0.0, 0.0, 2 * MAX_COORDINATE]], np.float32), bare, catalog, seed=bare)[0] == "absurd"
    assert len(checked_cloud(near, "x", max_range=10.0)) == 1
    for bad in (dict(max_range=10.0), dict(bounds=(-15.0, 15.5))):
        with pytest.raises(PayloadError, match="farther than|outside the box"):
            checked_cloud(far, "x", **bad)
    with pytest.raises(PayloadError, match="farther than 10000 m"):
        checked_cloud(np.array([[3.4e38, 0.0, 0.0]], np.float32), "x")


def test_the_shared_point_serializer_refuses_coordinates_no_lidar_returns():
    """Every selection codec's payload goes through pack_points: a crafted body of 1e30 m points
    (float32 or quantized with a huge step) is a PayloadError, not a cloud."""
    from lwbench import PayloadError, pack_points, unpack_points

    far = np.array([[1e30, 0.0, 0.0]], np.float32)
    with pytest.raises(ValueError, match="farther than 10000 m"):  # the encoder never writes it ...
        pack_points(far)
    with pytest.raises(PayloadError, match="farther than"):  # ... and a crafted body is refused
        unpack_points(struct.pack("<BI", 0, 1) + far.astype("<f4").tobytes(), "random")
    body = bytearray(pack_points(np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], np.float32), "quantized", 0.005))
    struct.pack_into("<f", body, 5 + 12, 1e30)  # the quantization step
    with pytest.raises(PayloadError, match="farther than"):
        unpack_points(bytes(body), "random")


@pytest.mark.skipif(importlib.util.find_spec("atheris") is None, reason="atheris is not installed here")
def test_atheris_harness_runs_a_bounded_campaign():
    tool = Path(__file__).parents[1] / "tools" / "fuzz_atheris.py"
    proc = subprocess.run([sys.executable, str(tool), "raw", "-atheris_runs=400", "-timeout=20",
                           "-rss_limit_mb=3072", "-seed=1"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
