"""The package's layers: ``core`` below everything, ``dsl`` and ``compiler`` above it, the
``runtime`` above them, and ``rdsl/cli.py`` (the command line) on top.

Every module of the package is parsed (nothing is imported) and each import, relative or
lazy inside a function, is resolved to an absolute module by ``rdsl.tools.import_graph``.
The rules:

- nothing under ``compiler/`` or ``dsl/`` imports the runtime, the top-level command line
  (``rdsl/cli.py``), or the runtime API that ``rdsl/__init__.py`` forwards (``rdsl.jit``...);
  only the plain constant ``rdsl.__version__`` may be taken from the top;
- nothing under ``core/`` imports anything of rdsl outside ``core/``, nor any third-party
  package but numpy (no llvmlite, no ctypes bindings: data and file lookup only).
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest
from rdsl.tools.import_graph import ROOT, Import, all_imports

# what compiler/ and dsl/ may take from the top-level package: constants that import nothing
TOP_CONSTANTS = frozenset({"__version__"})
# what core/ may import besides the standard library and itself
CORE_THIRD_PARTY = frozenset({"numpy"})


def _layer(module: str) -> str:
    """``rdsl.compiler.passes.lift`` -> ``compiler``; ``rdsl`` and ``rdsl.cli`` -> ``top``."""
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in ("cli", "__main__"):
        return "top"
    return parts[1]


def _violation(imp: Import) -> str | None:
    """Why ``imp`` breaks the layering, or None."""
    src, dst = _layer(imp.source), _layer(imp.target)
    if src in ("compiler", "dsl"):
        if dst == "runtime":
            return f"{src}/ imports the runtime ({imp.target})"
        if dst == "top" and (imp.target != "rdsl" or not imp.names
                             or not set(imp.names) <= TOP_CONSTANTS):
            what = ", ".join(imp.names) or imp.target
            return f"{src}/ imports the top-level API ({imp.target}: {what})"
    if src == "core" and dst != "core":
        return f"core/ imports {imp.target}, outside core/"
    return None


def violations(root: Path = ROOT) -> list[str]:
    """``file:line: why`` for every import under ``root`` that breaks the layering."""
    found = []
    for imp in all_imports(root):
        why = _violation(imp)
        if why:
            found.append(f"{imp.path.relative_to(root)}:{imp.line}: {why}")
    return found


def test_layers_are_respected():
    assert all_imports(), "found no imports at all: is ROOT the package?"
    bad = violations()
    assert not bad, "layering violations:\n" + "\n".join(bad)


def foreign_imports(root: Path = ROOT) -> list[str]:
    """``file:line: module`` for each import under ``core/`` of neither the standard library,
    numpy, nor rdsl (relative imports are checked by :func:`violations`)."""
    allowed = CORE_THIRD_PARTY | {"rdsl"} | sys.stdlib_module_names
    found = []
    for path in sorted((root / "core").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                if name.split(".")[0] not in allowed:
                    found.append(f"{path.relative_to(root)}:{node.lineno}: {name}")
    return found


def test_core_needs_only_numpy():
    bad = foreign_imports()
    assert not bad, "core/ imports third-party packages other than numpy:\n" + "\n".join(bad)


def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


PLANTED = {
    "__init__.py": "__version__ = '0'\n",
    "cli.py": "from .compiler import ok\n",
    "core/__init__.py": "",
    "core/data.py": "import numpy\nfrom . import more\nimport os.path\n",
    "core/jit.py": "from pathlib import Path\nimport llvmlite.ir\n",                # line 2
    "core/more.py": "from ..compiler.passes import p\n",                        # line 1
    "compiler/__init__.py": "",
    "compiler/ok.py": "from .. import __version__\nfrom ..core import data\n",
    "compiler/bad.py": "from .. import jit\nfrom ..cli import main\nimport rdsl\n",  # 1 2 3
    "compiler/passes/__init__.py": "",
    "compiler/passes/p.py": (
        "from ...core.data import x\n"
        "from ...runtime import embree\n"                                       # line 2
        "def f():\n"
        "    from ... import runtime\n"                                         # line 4
        "    import rdsl.runtime.api\n"                                         # line 5
    ),
    "dsl/__init__.py": "",
    "dsl/d.py": "from ..runtime.api import jit\n",                              # line 1
    "runtime/__init__.py": "",
    "runtime/api.py": "from ..compiler import ok\nfrom .. import cli\n",
    "runtime/embree.py": "from ..core.data import x\n",
    "tests/test_x.py": "from rdsl.runtime import api\n",  # not a module of the package
}


def test_planted_violations_are_found(tmp_path: Path):
    """Each kind of violation, relative, absolute and lazy, is reported at its line, and
    nothing else: the runtime and the top may import anything."""
    _write(tmp_path, PLANTED)
    found = {line.split(": ")[0] for line in violations(tmp_path)}
    assert found == {
        "core/more.py:1",
        "compiler/bad.py:1", "compiler/bad.py:2", "compiler/bad.py:3",
        "compiler/passes/p.py:2", "compiler/passes/p.py:4", "compiler/passes/p.py:5",
        "dsl/d.py:1",
    }


def test_planted_foreign_import_is_found(tmp_path: Path):
    _write(tmp_path, PLANTED)
    assert foreign_imports(tmp_path) == ["core/jit.py:2: llvmlite.ir"]


def test_relative_imports_resolve(tmp_path: Path):
    _write(tmp_path, PLANTED)
    targets = {(i.path.name, i.line): (i.target, i.names) for i in all_imports(tmp_path)}
    assert targets["p.py", 2] == ("rdsl.runtime.embree", ())
    assert targets["p.py", 4] == ("rdsl.runtime", ())
    assert targets["p.py", 1] == ("rdsl.core.data", ("x",))
    assert targets["ok.py", 1] == ("rdsl", ("__version__",))
    assert targets["data.py", 2] == ("rdsl.core.more", ())


@pytest.mark.parametrize("module, layer", [
    ("rdsl", "top"), ("rdsl.cli", "top"), ("rdsl.core.spectral", "core"),
    ("rdsl.compiler.backends.llvm", "compiler"), ("rdsl.runtime.render.cli", "runtime"),
])
def test_layer_of(module: str, layer: str):
    assert _layer(module) == layer
