"""Find every import between rdsl's modules and print the package-level import graph.

Each module of the package is parsed with :mod:`ast` (nothing is imported), every ``import``
and ``from ... import`` in it, lazy ones inside functions included, is resolved to an absolute
``rdsl.*`` module name, and the edges are grouped by layer (``dsl``, ``core``, ``compiler``,
``compiler.passes``, ...). ``tests/test_layering.py`` checks the layering rules on the same
edges; ``python -m rdsl.tools.import_graph`` prints the graph with a count per arrow.
"""

from __future__ import annotations

import argparse
import ast
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "rdsl"
# Directories of the repository that are not part of the installed package.
NOT_PACKAGE = frozenset({"tests", "bench", "examples", "docs", "stdlib", "build"})
# Most specific first: a module belongs to the first group its name starts with.
GROUPS = (
    "compiler.passes", "compiler.backends", "compiler", "runtime.scene", "runtime.render",
    "runtime", "core", "dsl", "tools",
)
TOP = "rdsl top"
# The order the graph is printed in: lower layers first.
LAYER_ORDER = (
    "dsl", "core", "compiler", "compiler.passes", "compiler.backends", "runtime",
    "runtime.scene", "runtime.render", "tools", TOP,
)


@dataclass(frozen=True)
class Import:
    """One import statement: where it is, the rdsl module it names and what it takes from it."""

    path: Path      # the importing file
    line: int
    source: str     # the importing module, e.g. rdsl.compiler.passes.lift
    target: str     # the imported module, e.g. rdsl.core.spectral
    names: tuple[str, ...] = ()  # attributes taken by ``from target import ...`` (not modules)


def package_files(root: Path = ROOT) -> list[Path]:
    """Every ``.py`` file of the package: the top level and each sub-package under it."""
    files = sorted(root.glob("*.py"))
    for init in sorted(root.rglob("__init__.py")):
        rel = init.parent.relative_to(root)
        if rel.parts and rel.parts[0] not in NOT_PACKAGE and not rel.parts[0].startswith("."):
            files.extend(sorted(init.parent.glob("*.py")))
    return [f for f in files if f.name != "setup.py"]


def module_name(path: Path, root: Path = ROOT) -> str:
    """``compiler/passes/lift.py`` -> ``rdsl.compiler.passes.lift`` (``__init__``: the package)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join([PACKAGE, *parts])


def _resolve_from(node: ast.ImportFrom, module: str, is_package: bool) -> str | None:
    """The absolute module a ``from`` statement reads from, or None if it is outside rdsl."""
    if node.level == 0:
        return node.module
    package = module if is_package else module.rpartition(".")[0]
    parts = package.split(".")
    if node.level - 1 >= len(parts):
        raise ValueError(f"relative import beyond the top of {PACKAGE} in {module}")
    base = ".".join(parts[: len(parts) - (node.level - 1)])
    return f"{base}.{node.module}" if node.module else base


def imports_of(path: Path, known: frozenset[str], root: Path = ROOT) -> list[Import]:
    """The rdsl imports of one file, one per statement and module: ``from pkg import mod``
    names the module ``pkg.mod``, ``from pkg import attr`` the module ``pkg`` (with ``attr``
    in :attr:`Import.names`)."""
    module = module_name(path, root)
    tree = ast.parse(path.read_text(), filename=str(path))
    found: list[Import] = []
    for node in ast.walk(tree):
        targets: dict[str, list[str]] = {}
        if isinstance(node, ast.Import):
            for alias in node.names:
                targets.setdefault(alias.name, [])
        elif isinstance(node, ast.ImportFrom):
            base = _resolve_from(node, module, path.name == "__init__.py")
            for alias in node.names if base else ():
                sub = f"{base}.{alias.name}"
                if sub in known:
                    targets.setdefault(sub, [])
                else:
                    targets.setdefault(base, []).append(alias.name)
        for target, names in targets.items():
            if target == PACKAGE or target.startswith(PACKAGE + "."):
                found.append(Import(path, node.lineno, module, target, tuple(names)))
    return found


def all_imports(root: Path = ROOT) -> list[Import]:
    """The rdsl imports of every module of the package."""
    files = package_files(root)
    known = frozenset(module_name(f, root) for f in files)
    return [imp for f in files for imp in imports_of(f, known, root)]


def group_of(module: str) -> str:
    """The layer a module belongs to: ``rdsl.runtime.render.bsdfs`` -> ``runtime.render``."""
    rest = module.removeprefix(PACKAGE).lstrip(".")
    for group in GROUPS:
        if rest == group or rest.startswith(group + "."):
            return group
    return TOP


def graph(imports: list[Import]) -> Counter[tuple[str, str]]:
    """Import statements counted per (importing group, imported group), within a group too."""
    return Counter((group_of(i.source), group_of(i.target)) for i in imports)


def format_graph(edges: Counter[tuple[str, str]]) -> str:
    """One line per arrow, grouped by importer in layer order."""
    def rank(edge: tuple[tuple[str, str], int]) -> tuple[int, int]:
        (src, dst), _ = edge
        return LAYER_ORDER.index(src), LAYER_ORDER.index(dst)

    lines = []
    for (src, dst), count in sorted(edges.items(), key=rank):
        lines.append(f"{src:>18} -> {dst:<18} {count:4d}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Print the import graph; ``--cross`` leaves out imports within a group."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cross", action="store_true", help="only imports between groups")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root")
    args = parser.parse_args(argv)
    edges = graph(all_imports(args.root))
    if args.cross:
        edges = Counter({k: v for k, v in edges.items() if k[0] != k[1]})
    print(format_graph(edges))


if __name__ == "__main__":
    main()
