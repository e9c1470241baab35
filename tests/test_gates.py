"""The pytest plugin's gates on a toy codec: a gate passes, a gate fails with a message a person
can act on, results are reused from a store, thresholds are checked against real metric ids."""

from __future__ import annotations

import textwrap

import pytest

pytest_plugins = ["pytester"]

TOY = '''
import numpy as np
from lwbench import Frame, Param, RepresentationCodec


class JitterCodec(RepresentationCodec):
    """Raw float32 points moved along their ray by a seeded +-jitter (m): a known range error."""

    name = "jitter"
    params = (Param("jitter", "float", 0.01, "range error (m)", low=0.0),)

    def encode(self, frame: Frame) -> bytes:
        rng = np.random.default_rng(frame.index)
        r = np.linalg.norm(frame.points, axis=1, keepdims=True)
        scale = 1 + rng.uniform(-1, 1, r.shape) * self.config["jitter"] / r
        pts = (frame.points * scale).astype("<f4")
        return self.make_payload(frame, {"n": len(pts)}, pts.tobytes())

    def decode(self, data: bytes) -> np.ndarray:
        p = self.read_payload(data)
        return np.frombuffer(p.body, "<f4").reshape(self.meta_field(p, "n", int), 3).copy()
'''


@pytest.fixture
def project(pytester, kitti_folder):
    pytester.makepyfile(toy_codec=TOY)
    pytester.makeini("[pytest]\naddopts = -p no:dash -p no:cacheprovider\n")
    return pytester, kitti_folder


# Each inner session runs in a subprocess: in-process runs drop the modules they imported, and
# native extensions (Open3D, SciPy's k-d tree) cannot be imported twice in one process.


@pytest.mark.heavy
def test_a_gate_passes_and_fails_as_its_thresholds_say(project):
    pytester, folder = project
    pytester.makepyfile(test_toy=textwrap.dedent(f'''
        from toy_codec import JitterCodec

        def test_small_jitter_passes(lwbench_gate):
            r = lwbench_gate(JitterCodec, params={{"jitter": 0.005}}, dataset="{folder}", frames=2,
                             max_range_rmsd=0.01, min_coverage=0.9)
            assert r.frames == 2

        def test_large_jitter_fails(lwbench_gate):
            lwbench_gate(JitterCodec, params={{"jitter": 0.2}}, dataset="{folder}", frames=2,
                         max_range_rmsd=0.01, min_ratio=0.9)
    '''))
    result = pytester.runpytest_subprocess("-q")
    result.assert_outcomes(passed=1, failed=1)
    out = result.stdout.str()
    assert "lwbench gate failed: jitter(jitter=0.2) on " in out
    assert "range_rmsd = " in out and "required <= 0.01 m" in out and "worst frame" in out
    assert "ok: ratio" in out  # the thresholds it met are listed too
    print(out[out.index("lwbench gate failed"):][:600])  # shown in the closing note


@pytest.mark.heavy
def test_a_gate_reuses_a_store_and_refuses_unknown_metric_ids(project, tmp_path):
    pytester, folder = project
    store = tmp_path / "ci.sqlite"
    pytester.makepyfile(test_reuse=textwrap.dedent(f'''
        import pytest
        from toy_codec import JitterCodec

        def test_gate(lwbench_gate):
            lwbench_gate(JitterCodec, dataset="{folder}", frames=3, max_range_rmsd=0.05)

        def test_typo(lwbench_gate):
            with pytest.raises(Exception, match="unknown metric id 'rmsd'"):
                lwbench_gate(JitterCodec, dataset="{folder}", frames=3, max_rmsd=0.05)
    '''))
    pytester.runpytest_subprocess("-q", f"--lwbench-store={store}").assert_outcomes(passed=2)
    from lwbench.results.store import ResultStore

    with ResultStore(store, readonly=True) as s:
        rows_after_first = s.count()
        created = sorted(r.created for r in s.rows())
    assert rows_after_first == 3
    pytester.runpytest_subprocess("-q", f"--lwbench-store={store}").assert_outcomes(passed=2)
    with ResultStore(store, readonly=True) as s:
        assert s.count() == 3 and sorted(r.created for r in s.rows()) == created  # cache hits, no re-encode


@pytest.mark.heavy
def test_a_speed_gate_records_quality_in_the_benchmark_json(project, tmp_path):
    pytester, folder = project
    pytester.makepyfile(test_speed=textwrap.dedent(f'''
        def test_speed(lwbench_benchmark):
            lwbench_benchmark("raw", dataset="{folder}", frames=2, rounds=2, min_coverage=1.0)
    '''))
    out = tmp_path / "bench.json"
    result = pytester.runpytest_subprocess("-q", f"--benchmark-json={out}")
    result.assert_outcomes(passed=1)
    import json

    (bench,) = json.loads(out.read_text())["benchmarks"]
    assert bench["extra_info"]["codec"] == "raw" and bench["extra_info"]["coverage"] == 1.0
    assert bench["extra_info"]["ratio"] > 0.9
