"""README's Layout section names every module and subpackage of lwbench/ and nothing that is gone
(issue 34: it listed ``io.py``, a package by then, and omitted 13 modules)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _layout_block() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## Layout", 1)[1]
    return section.split("```", 2)[1]


def _named_in_core(block: str) -> set[str]:
    """The ``x.py`` and ``x/`` names on the indented (core) lines of the block."""
    names: set[str] = set()
    for line in block.splitlines():
        if not line.startswith("  "):
            continue
        listing = re.split(r"\s{2,}", line.strip(), maxsplit=1)[0]
        names.update(w for w in listing.split() if w.endswith((".py", "/")))
    return names


def test_the_layout_names_every_core_module_and_no_missing_one():
    on_disk = {p.name for p in (ROOT / "lwbench").glob("*.py") if p.name != "__init__.py"}
    on_disk |= {p.name + "/" for p in (ROOT / "lwbench").iterdir() if (p / "__init__.py").is_file()}
    named = _named_in_core(_layout_block())
    assert not on_disk - named, f"README's Layout omits {sorted(on_disk - named)}"
    assert not named - on_disk, f"README's Layout names what is not in lwbench/: {sorted(named - on_disk)}"
