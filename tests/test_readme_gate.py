"""The gate example in the README, copied into a fresh project folder, runs and passes."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.heavy
def test_the_readme_gate_example_runs_in_a_fresh_project(tmp_path):
    text = README.read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "lwbench_gate" in b]
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "test_codec_gates.py").write_text(block)
    res = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:dash", "-p", "no:cacheprovider", str(tests)],
        cwd=tmp_path, capture_output=True, text=True,
    )
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    assert "2 passed" in res.stdout
