"""docs/design.md: core knows no metric or codec by name. The import rules (test_layering.py)
cannot see a name written as a string, so this test reads the code: no string in ``lwbench/``
(docstrings aside) is the name of an installed codec or metric, or a metric id -- what core needs
of a metric it finds through a declaration (``MetricId.role``, ``MetricId.quantity``).

A few words are core's own vocabulary that a plugin happens to share; each is listed with why.
"""

from __future__ import annotations

import ast
from pathlib import Path

from lwbench.registry import get_registry

ROOT = Path(__file__).resolve().parents[1]

#: Core's own words that equal an installed name, and what they are in core.
CORE_WORDS = {
    "ratio": "the selection codecs' budget parameter, which core declares (lwbench.BUDGET_PARAMS)",
    "bytes": "a size field of core's own records (the stream's event log, `lwbench inspect`, a payload index)",
    "voxel": "the stream base's map voxel setting (lwbench stream --voxel)",
    "encode_ms": "a timing core measures around encode (Evaluation.timings_ms), which the runtime metric reports",
    "decode_ms": "a timing core measures around decode (Evaluation.timings_ms)",
    "select_ms": "a timing core measures around a selection codec's select (Evaluation.timings_ms)",
    "runtime": "a metric role core declares (lwbench.METRIC_ROLES: what the report draws as a bar)",
}


def installed_names() -> set[str]:
    reg = get_registry()
    return {*reg.codecs, *reg.frame_metrics, *reg.sequence_metrics, *reg.metric_info()}


def names_written_in_core(names: set[str]) -> list[str]:
    found = []
    for path in sorted((ROOT / "lwbench").rglob("*.py")):
        tree = ast.parse(path.read_text())
        docstrings = {
            id(node.body[0].value)
            for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)
        }
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings
                    and node.value in names and node.value not in CORE_WORDS):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value!r}")
    return found


def test_core_writes_no_codec_or_metric_name():
    assert names_written_in_core(installed_names()) == []


def test_the_check_sees_a_name_written_in_core(tmp_path, monkeypatch):
    """The check itself can fail: a core module that names a metric id is found."""
    fake_root = tmp_path / "root"
    (fake_root / "lwbench").mkdir(parents=True)
    (fake_root / "lwbench" / "board.py").write_text('"""Docstrings may say range_rmsd."""\nSORT = "range_rmsd"\n')
    monkeypatch.setattr(__import__(__name__), "ROOT", fake_root)
    assert names_written_in_core({"range_rmsd", "raw"}) == ["lwbench/board.py:2: 'range_rmsd'"]
