"""The import graph of lwbench's source folders: module sizes, import circles, layering breaches.

    python tests/_import_graph.py            # sizes of lwbench/ modules over 300 lines, circles, breaches
    python tests/_import_graph.py --edges    # also every edge inside lwbench/

Every ``import`` statement counts, at module level or inside a function (a lazy import still
ties two modules together). Edges go to the module named: ``from lwbench.run import X`` is an
edge to the package ``lwbench.run``, ``from lwbench.run.plan import X`` to ``lwbench.run.plan``.
The layering rules (tests/test_layering.py holds the project to them):

- core (``lwbench``) never imports a plugin (``lwbench_plugins``) or a built-in metric
  (``lwbench_metrics``);
- a plugin folder (``plugins/<name>``, ``metrics``) imports from lwbench only the public API --
  ``lwbench``, ``lwbench.geometry``, ``lwbench.io``, ``lwbench.testing`` -- and otherwise its own
  modules. The built-in loaders (``plugins/files``) are such a folder; so is every example plugin
  under ``examples/`` (:data:`EXAMPLES`), checked as a third-party package would be.
"""

from __future__ import annotations

import argparse
import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Source folder -> the import name it is installed under (pyproject.toml's package-dir).
PACKAGES = {"lwbench": "lwbench", "metrics": "lwbench_metrics", "plugins": "lwbench_plugins"}
PUBLIC = ("lwbench", "lwbench.geometry", "lwbench.io", "lwbench.testing")


@dataclass(frozen=True)
class Module:
    name: str  # import name, e.g. lwbench.run.plan
    path: Path
    lines: int
    is_package: bool


#: The example third-party plugins: each ``examples/<dist>/`` with a pyproject.toml, whose
#: top-level modules and packages (not its tests) are installed under their own names.
EXAMPLES = "examples"


def _add(out: dict[str, Module], base: Path, path: Path, import_name: str | None) -> None:
    rel = path.relative_to(base).with_suffix("")
    parts = [import_name, *rel.parts] if import_name else list(rel.parts)
    is_package = parts[-1] == "__init__"
    if is_package:
        parts = parts[:-1]
    out[".".join(parts)] = Module(".".join(parts), path, len(path.read_text().splitlines()), is_package)


def example_modules(root: Path = ROOT) -> dict[str, Module]:
    """The modules of every example plugin under ``examples/``, by import name."""
    out: dict[str, Module] = {}
    for project in sorted((root / EXAMPLES).glob("*/pyproject.toml")):
        base = project.parent
        for path in sorted(base.glob("*.py")):
            _add(out, base, path, None)
        for pkg in sorted(p for p in base.iterdir() if (p / "__init__.py").is_file() and p.name != "tests"):
            for path in sorted(pkg.rglob("*.py")):
                _add(out, base, path, None)
    return out


def modules(root: Path = ROOT) -> dict[str, Module]:
    """Every Python module of the three source folders and of the example plugins, by import name."""
    out: dict[str, Module] = {}
    for folder, import_name in PACKAGES.items():
        for path in sorted((root / folder).rglob("*.py")):
            _add(out, root / folder, path, import_name)
    return {**out, **example_modules(root)}


def _imports(module: Module, known: dict[str, Module] | None = None) -> Iterator[tuple[str, int]]:
    """``(imported module, line)`` for every import statement (relative ones resolved; with
    ``known``, ``from package import name`` is the submodule ``package.name`` when there is one)."""
    tree = ast.parse(module.path.read_text(), str(module.path))
    package = module.name if module.is_package else module.name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                yield (sub if known is not None and sub in known else target), node.lineno


def edges(mods: dict[str, Module]) -> dict[str, set[str]]:
    """module -> the modules of the three folders it imports (a name that is an attribute of a
    package, ``from lwbench.run import plan``, counts as the submodule when one exists)."""
    out: dict[str, set[str]] = {}
    for name, mod in mods.items():
        targets = set()
        for target, _ in _imports(mod, mods):
            if target in mods and target != name:
                targets.add(target)
        out[name] = targets
    return out


def circles(graph: dict[str, set[str]], within: str = "lwbench") -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), among ``within``'s."""
    nodes = [n for n in graph if n == within or n.startswith(within + ".")]
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in nodes:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for n in nodes:
        if n not in index:
            visit(n)
    return sorted(found)


def breaches(mods: dict[str, Module]) -> list[str]:
    """Imports that break the layering rules (see the module docstring), as readable lines."""
    out = []
    for name, mod in mods.items():
        top = name.split(".")[0]
        own = name if top == "lwbench_metrics" else ".".join(name.split(".")[:2])
        for target, line in _imports(mod):
            where = f"{mod.path.relative_to(ROOT) if mod.path.is_relative_to(ROOT) else mod.path}:{line}"
            if top == "lwbench":
                if target.split(".")[0] in ("lwbench_plugins", "lwbench_metrics"):
                    out.append(f"{where}: core imports the plugin module {target}")
                continue
            own_prefix = "lwbench_metrics" if top == "lwbench_metrics" else own
            if target == own_prefix or target.startswith(own_prefix + "."):
                continue
            head = target.split(".")[0]
            if head == "lwbench" and target not in PUBLIC:
                out.append(f"{where}: {name} imports {target}, which is not the public API ({', '.join(PUBLIC)})")
            elif head in ("lwbench_plugins", "lwbench_metrics"):
                out.append(f"{where}: {name} imports another plugin's module {target}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", action="store_true", help="print every edge inside lwbench/")
    parser.add_argument("--min-lines", type=int, default=300, help="list lwbench/ modules at least this long")
    args = parser.parse_args()
    mods = modules()
    graph = edges(mods)
    core = sorted((m for m in mods.values() if m.name.split(".")[0] == "lwbench"), key=lambda m: -m.lines)
    print(f"lwbench/ modules of {args.min_lines}+ lines:")
    for m in core:
        if m.lines >= args.min_lines:
            print(f"  {m.lines:5d}  {m.path.relative_to(ROOT)}")
    found = circles(graph)
    print(f"import circles inside lwbench/: {len(found)}")
    for comp in found:
        print("  " + " <-> ".join(comp))
    bad = breaches(mods)
    print(f"layering breaches: {len(bad)}")
    for line in bad:
        print("  " + line)
    if args.edges:
        for name in sorted(graph):
            if name.startswith("lwbench") and not name.startswith(("lwbench_plugins", "lwbench_metrics")):
                print(f"{name} -> {', '.join(sorted(graph[name])) or '-'}")


if __name__ == "__main__":
    main()
