"""The plugin boundary, held by the code itself: who may import whom (tests/_import_graph.py).

- core (``lwbench``) never imports a plugin or a built-in metric module;
- every plugin folder (``plugins/<name>``, ``metrics``) imports from lwbench only the public API
  (``lwbench``, ``lwbench.geometry``, ``lwbench.io``, ``lwbench.testing``) -- the same boundary a
  third-party plugin has; the built-in loaders (``plugins/files``) included, and the example
  third-party plugins under ``examples/`` checked the same way (issue 34, item 3);
- production code never uses the test kit or another module's private helpers;
- no import circle anywhere in the tree, plugins and metrics included (lazy imports inside
  functions count too).
"""

from __future__ import annotations

import ast
from pathlib import Path

import _import_graph as graph_tool
import pytest

ROOT = Path(__file__).resolve().parent.parent
MODULES = graph_tool.modules()
GRAPH = graph_tool.edges(MODULES)


def test_core_never_imports_a_plugin_and_plugins_import_only_the_public_api():
    assert graph_tool.breaches(MODULES) == []


@pytest.mark.parametrize("root", ["lwbench", "lwbench_plugins", "lwbench_metrics"])
def test_there_is_no_import_circle_in_the_tree(root):
    # Plugins included (issue 34: vsgp's encoder and decoder imported each other).
    assert graph_tool.circles(GRAPH, root) == []


def test_the_public_modules_exist_and_the_rules_see_every_plugin_folder():
    for name in graph_tool.PUBLIC:
        assert name in MODULES, name
    plugin_folders = {p.name for p in (ROOT / "plugins").iterdir() if (p / "__init__.py").is_file()}
    seen = {m.split(".")[1] for m in MODULES if m.startswith("lwbench_plugins.") and m.count(".") >= 1}
    assert plugin_folders <= seen
    # The built-in loaders are a plugin folder, not core; the example plugins are checked too.
    assert "lwbench_plugins.files" in MODULES and "lwbench.loaders" not in MODULES
    assert {"lwbench_example_codec", "lwbench_example_loader"} <= set(graph_tool.example_modules())


def test_the_layering_rule_catches_a_loader_that_reaches_into_core(tmp_path):
    """What the built-in loaders did before they moved (issue 34, item 3): a plugin deriving its
    sensor through a private core module is a breach; through the public API it is not."""
    example = tmp_path / "examples" / "lwbench-bad-loader"
    example.mkdir(parents=True)
    (example / "pyproject.toml").write_text("[project]\nname = 'lwbench-bad-loader'\n")
    (example / "bad_loader.py").write_text(
        "from lwbench.sensors.derive import derive_sensor\nfrom lwbench.scan_picking import pick_scans\n"
        "from lwbench import Dataset, derive_sensor as ok\nfrom lwbench.io import read_point_file\n"
    )
    mods = graph_tool.example_modules(tmp_path)
    found = [line.split(": ", 1)[1] for line in graph_tool.breaches(mods)]
    assert [f.split(",")[0] for f in found] == [
        "bad_loader imports lwbench.sensors.derive", "bad_loader imports lwbench.scan_picking",
    ]


def _imported_names(path: Path) -> set[tuple[str, str]]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            out |= {(node.module, a.name) for a in node.names}
    return out


def _private(module: str, name: str) -> bool:
    return (module == "lwbench" or module.startswith("lwbench.")) and name.startswith("_") and not name.startswith("__")


def test_production_code_uses_no_test_kit_and_no_private_helper_of_another_module():
    offenders = []
    for mod in MODULES.values():
        if mod.name.startswith("lwbench.testing"):
            continue
        for module, name in _imported_names(mod.path):
            if module.startswith("lwbench.testing") or (_private(module, name) and module != mod.name):
                offenders.append(f"{mod.path.relative_to(ROOT)}: from {module} import {name}")
    assert offenders == []


def test_no_metric_id_is_written_into_the_board_the_report_or_the_gates():
    """What an id means to the board -- sort direction, default column, headline, what the report
    plots, the quality guard -- is declared by its metric (lwbench.MetricId), so a third-party
    metric is treated as a built-in one: these modules hold no metric id as a string."""
    from lwbench.registry import get_registry

    ids = set(get_registry().metric_info())
    board = ("lwbench.results.leaderboard", "lwbench.results.board_table", "lwbench.results.report",
             "lwbench.pytest_plugin", "lwbench.gates")
    for name in board:
        tree = ast.parse(MODULES[name].path.read_text())
        docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                      if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef)) and n.body
                      and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        strings = {n.value for n in ast.walk(tree)
                   if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docstrings}
        assert not strings & ids, f"{name} names metric ids {sorted(strings & ids)}"


def test_the_public_api_is_written_down_once_and_agrees_with_the_code():
    """docs/plugins.md's "The public API" lists exactly what lwbench, lwbench.geometry, lwbench.io
    and lwbench.testing export (their __all__)."""
    import re

    import lwbench
    import lwbench.geometry
    import lwbench.io
    import lwbench.testing

    text = (ROOT / "docs" / "plugins.md").read_text()
    section = text[text.index("## The public API"):]
    parts = re.split(r"\*\*`(lwbench(?:\.\w+)?)`\*\*", section)
    listed = {parts[i]: set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", parts[i + 1])) for i in range(1, len(parts), 2)}
    for module in (lwbench, lwbench.geometry, lwbench.io, lwbench.testing):
        assert listed[module.__name__] == set(module.__all__), module.__name__


def test_no_module_is_over_500_lines():
    """Issue 34: a module that needs more has two subjects (the localization map left
    localization.py at 514 lines, the k-means start left the mixture at 538)."""
    long = {m.name: m.lines for m in MODULES.values() if m.lines > 500}
    assert not long, f"split these modules: {long}"
