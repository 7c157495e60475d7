"""Module loading: the implicit prelude, the main file and, depth first, its imports.

An ``import a.b;`` is looked up as ``a/b.rdsl`` next to the importing file, then in the
search paths, then in the stdlib.  A stdlib file's imports skip the search paths: a user's
plugin folder (``rdsl render --plugins``) holding a ``warp.rdsl`` must not replace the
stdlib's for the stdlib's own plugins.  Each file is parsed once; a cycle is an error.
"""

from __future__ import annotations

from pathlib import Path

from ..compiler.diagnostics import read_source_file
from . import ast as A
from . import parse_ahead
from .parser import parse
from .program import ModuleInfo
from .types import err

STDLIB = Path(__file__).resolve().parent.parent / "stdlib"


class Loader:
    """Parses the main file and, depth first, everything it imports."""

    def __init__(self, search_paths: list[Path]) -> None:
        self.search_paths = search_paths
        self.modules: dict[str, ModuleInfo] = {}
        self.order: list[ModuleInfo] = []
        self.stack: list[str] = []

    def load_path(self, path: Path, is_main: bool = False) -> ModuleInfo:
        key = str(path.resolve())
        return self.load_text(read_source_file(path), str(path), key, is_main)

    def load_text(self, text: str, filename: str, key: str, is_main: bool) -> ModuleInfo:
        if key in self.modules:
            mod = self.modules[key]
            mod.is_main = mod.is_main or is_main
            return mod
        prog = parse(text, filename)
        mod = ModuleInfo(key, prog, is_main)
        self.stack.append(key)
        for imp in prog.imports:
            self._import(imp, filename)
        self.stack.pop()
        self.modules[key] = mod
        self.order.append(mod)
        return mod

    def _import(self, imp: A.Import, importer: str) -> None:
        rel = Path(*imp.path).with_suffix(".rdsl")
        for d in import_dirs(importer, self.search_paths):
            cand = d / rel
            if cand.is_file():
                key = str(cand.resolve())
                if key in self.stack:
                    cycle = self.stack[self.stack.index(key):] + [key]
                    names = " -> ".join(Path(k).name for k in cycle)
                    hint = ""
                    if len(cycle) == 2 and (STDLIB / rel).is_file() and d != STDLIB:
                        hint = (f": the file's name hides the stdlib's `{'.'.join(imp.path)}` "
                                f"({STDLIB / rel}) from the files next to it; rename the file")
                    raise err(f"import cycle: {names}{hint}", imp.loc)
                if key not in self.modules:
                    self.load_path(cand)
                return
        name = ".".join(imp.path)
        where = "next to the importing file" + (", in the search paths"
                                                 if self.search_paths else "")
        raise err(f"cannot find module `{name}` (looked for `{rel.as_posix()}` {where} and "
                  "in the stdlib)", imp.loc)


def import_dirs(importer: str, search_paths: list[Path]) -> list[Path]:
    """Where an import of ``importer`` is looked up, in order: next to it, in the search
    paths (not for a stdlib file), in the stdlib."""
    dirs = [] if importer.startswith("<") else [Path(importer).parent]
    if not in_stdlib(importer):
        dirs += search_paths
    return [*dirs, STDLIB]


def in_stdlib(filename: str) -> bool:
    """Whether ``filename`` is a file of the stdlib (its imports never see search paths)."""
    if filename.startswith("<"):
        return False
    return Path(filename).resolve().is_relative_to(STDLIB.resolve())


def prelude() -> list[Path]:
    """The implicitly imported stdlib files."""
    types = STDLIB / "types.rdsl"
    math = STDLIB / "math.rdsl"
    special = STDLIB / "special.rdsl"
    # They are part of the package; a broken prelude is an rdsl bug, and it is reported as
    # a diagnostic in the prelude file rather than skipped, so nothing half-works silently.
    return [p for p in (types, math, special) if p.is_file()]


def load_program(source: str, filename: str, search_paths: list[Path] | None = None,
                 path: Path | None = None) -> list[ModuleInfo]:
    """The prelude, the main file (text ``source``) and its imports, dependencies first."""
    loader = Loader([Path(p) for p in (search_paths or [])])
    helper = parse_ahead.start(source, filename, prelude(),
                               lambda importer: import_dirs(importer, loader.search_paths))
    try:
        for p in prelude():
            loader.load_path(p).prelude = True
        key = str(path.resolve()) if path is not None else f"<main>{filename}"
        loader.load_text(source, filename, key, is_main=True)
    finally:
        if helper is not None:
            helper.stop()
    return loader.order
