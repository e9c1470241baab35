"""A built-in codec's ``version`` is part of every result key: when a change alters what a codec
writes or reads, the version must change, or the store serves the old code's numbers as cache
hits (issue 34, item 7). This test makes that a decision someone takes, not a thing to remember.

``codec_sources.json`` records, per built-in codec, its ``version`` and a hash of its plugin
folder's code (the AST with docstrings left out, so comments, docstrings and formatting do not
count). When the code changes, this test fails until the record is updated:

- the change alters encode or decode: bump the codec's ``version``, then record it;
- it does not (a refactor): record the new hash with the same version -- a reviewer sees both.

    python tests/test_codec_versions.py     # rewrite the record from the code as it is

Known limit: core code a codec calls (the point serializer, the payload header) is not hashed
here; those carry their own format versions (``lwbench.payload``).
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import sys
from pathlib import Path

RECORD = Path(__file__).with_name("codec_sources.json")


def _strip_docstrings(tree: ast.AST) -> ast.AST:
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant) \
                    and isinstance(body[0].value.value, str):
                node.body = body[1:] or [ast.Pass()]
    return tree


def source_hash(folder: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*.py")):
        tree = _strip_docstrings(ast.parse(path.read_text(), str(path)))
        digest.update(str(path.relative_to(folder)).encode())
        digest.update(ast.dump(tree, annotate_fields=False, include_attributes=False).encode())
    return digest.hexdigest()[:16]


def current() -> dict[str, dict[str, str]]:
    from lwbench.registry import get_registry

    out = {}
    for name, cls in sorted(get_registry().codecs.items()):
        if not cls.__module__.startswith("lwbench_plugins."):
            continue  # a third-party codec installed here is its own project's business
        folder = Path(inspect.getfile(sys.modules[cls.__module__])).parent
        out[name] = {"version": str(cls.version), "source": source_hash(folder)}
    return out


def test_every_built_in_codec_change_is_recorded_with_its_version():
    recorded = json.loads(RECORD.read_text())
    now = current()
    assert sorted(now) == sorted(recorded), "codecs added or removed: run python tests/test_codec_versions.py"
    stale = {}
    for name, entry in now.items():
        if entry != recorded[name]:
            same_version = entry["version"] == recorded[name]["version"]
            stale[name] = ("code changed, version did not: bump it if encode/decode output changed, "
                           "then run python tests/test_codec_versions.py" if same_version else
                           "version bumped: run python tests/test_codec_versions.py to record it")
    assert not stale, stale


def test_the_hash_ignores_docstrings_and_comments_but_not_code(tmp_path):
    (tmp_path / "a.py").write_text('"""Doc."""\n# note\ndef f():\n    """Doc."""\n    return 1\n')
    base = source_hash(tmp_path)
    (tmp_path / "a.py").write_text('"""Other doc."""\n\ndef f():  # another note\n    return 1\n')
    assert source_hash(tmp_path) == base
    (tmp_path / "a.py").write_text('"""Doc."""\ndef f():\n    return 2\n')
    assert source_hash(tmp_path) != base


if __name__ == "__main__":
    RECORD.write_text(json.dumps(current(), indent=1, sort_keys=True) + "\n")
    print(f"recorded {RECORD}")
