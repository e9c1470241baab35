"""Replaying the regression corpus (tests/corpus/): every crafted payload that once broke a
decoder must now be refused with ``PayloadError`` or decode to a cloud within reach.

The cases decode in the fuzz decode server (:class:`lwbench.fuzz.DecodeServer`: a sandboxed
child with a memory ceiling and a per-case timeout), so a regression that hangs or bombs fails
one case instead of the test run. A case is judged against its own sensor's reach when it
names one the server knows (the kit's and the fuzz scans' sensors), else against 10 km.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from lwbench.fuzz import class_ref, fuzz_sensors, shared_server
from lwbench.registry import get_registry
from lwbench.testing import check_frames

CORPUS = Path(__file__).parent / "corpus"
CASES = sorted(CORPUS.glob("*.lwb"))
REGISTRY = get_registry()


def test_the_corpus_is_there_and_names_registered_codecs():
    assert CASES, f"no regression cases under {CORPUS}"
    assert {p.name.split("-")[0] for p in CASES} <= set(REGISTRY.codecs)


@pytest.mark.parametrize("case", CASES, ids=[p.stem for p in CASES])
def test_a_corpus_case_is_refused_or_decodes_within_reach(case):
    codec = case.name.split("-")[0]
    data = case.read_bytes()
    server = shared_server()
    kit = [f.sensor.to_dict(full=True) for f in check_frames().values()]
    server.register_sensors([*fuzz_sensors(), *kit])
    outcome = server.decode(class_ref(REGISTRY.codec(codec)), {}, data, judged_by=data)
    assert outcome.kind in ("ok", "PayloadError") and outcome.verdict == "fine", (
        f"{case.name}: {outcome.verdict} ({outcome.kind}: {outcome.message}; {outcome.cpu_s:.2f} s CPU)"
    )
