"""How pytest shows lwbench's gates: a failed gate is its message (not lwbench's source), and the
README's benchmark recipe (``pytest --benchmark-only --benchmark-autosave``) runs the
``lwbench_benchmark`` tests instead of skipping them as non-benchmarks."""

from __future__ import annotations

import json
import textwrap

import pytest

pytest_plugins = ["pytester"]


@pytest.fixture
def project(pytester, kitti_folder):
    pytester.makeini("[pytest]\naddopts = -p no:dash -p no:cacheprovider\n")
    return pytester, kitti_folder


# Subprocesses: native extensions (Open3D, SciPy) cannot be imported twice in one process.


@pytest.mark.heavy
def test_a_failed_gate_shows_its_message_and_not_lwbench_source(project):
    pytester, folder = project
    pytester.makepyfile(test_gate=textwrap.dedent(f'''
        def test_raw_is_not_that_small(lwbench_gate):
            lwbench_gate("raw", dataset="{folder}", frames=2, min_ratio=100)
    '''))
    result = pytester.runpytest_subprocess("-q")
    result.assert_outcomes(failed=1)
    out = result.stdout.str()
    section = out[out.index("_ test_raw_is_not_that_small _"):out.index("short test summary")]
    assert "lwbench gate failed: raw on " in section and "ratio = " in section and "required >= 100" in section
    assert "test_gate.py:2, in test_raw_is_not_that_small)" in section  # where, in the user's test
    assert "FAILED test_gate.py::test_raw_is_not_that_small - lwbench gate failed: raw on" in out
    for source in ("def require", "raise GateFailure", "lwbench/gates.py", "run_gate("):
        assert source not in section, section
    assert len(section.splitlines()) <= 8, section


@pytest.mark.heavy
def test_a_gate_failure_can_still_be_expected(project):
    pytester, folder = project
    pytester.makepyfile(test_expect=textwrap.dedent(f'''
        import pytest
        from lwbench.gates import GateFailure

        def test_expected(lwbench_gate):
            with pytest.raises(GateFailure, match="ratio"):
                lwbench_gate("raw", dataset="{folder}", frames=1, min_ratio=100)
    '''))
    pytester.runpytest_subprocess("-q").assert_outcomes(passed=1)


@pytest.mark.heavy
def test_the_readme_benchmark_recipe_runs_the_benchmark(project):
    pytester, folder = project
    pytester.makepyfile(test_speed=textwrap.dedent(f'''
        def test_speed(lwbench_benchmark):
            lwbench_benchmark("raw", dataset="{folder}", frames=1, rounds=2)

        def test_not_a_benchmark():
            pass
    '''))
    result = pytester.runpytest_subprocess("-q", "--benchmark-only", "--benchmark-autosave")
    result.assert_outcomes(passed=1, skipped=1)  # the plain test is the one skipped
    (saved,) = (pytester.path / ".benchmarks").rglob("*.json")
    (bench,) = json.loads(saved.read_text())["benchmarks"]
    assert bench["name"] == "test_speed" and bench["extra_info"]["codec"] == "raw"
    assert bench["stats"]["rounds"] == 2
    pytester.runpytest_subprocess("-q", "--benchmark-skip").assert_outcomes(passed=1, skipped=1)
