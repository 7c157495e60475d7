"""Which files a program is made of, found without importing the compiler (the kernel cache
hashes them before deciding whether to compile)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

from .diagnostics import read_source_file

STDLIB = Path(__file__).resolve().parent.parent / "stdlib"
PRELUDE = ("types", "math", "special")


def is_path(source_or_path: str | os.PathLike) -> bool:
    """The one rule for "is this a file or source text?", used by every entry point (``jit``,
    ``check``, the kernel cache).  A path object is a file.  A string is source text if it
    holds a newline or is longer than any path; otherwise it is a file if it ends in
    ``.rdsl`` (so a missing one says it cannot be read rather than failing to parse) or names
    an existing file."""
    if isinstance(source_or_path, os.PathLike):
        return True
    s = str(source_or_path)
    if "\n" in s or len(s) >= 4096:
        return False
    if s.endswith(".rdsl"):
        return True
    try:
        return Path(s).is_file()
    except (OSError, ValueError):
        return False


def read_source(source_or_path: str | os.PathLike) -> tuple[str, Path | None]:
    """The program's text, and its file (None for source text); a file that cannot be read
    is a diagnostic naming it."""
    if not is_path(source_or_path):
        return str(source_or_path), None
    path = Path(source_or_path)
    return read_source_file(path), path


def source_files(source_or_path: str | Path, search_paths: Iterable[str | Path] = (), *,
                 filename: str | None = None) -> list[Path]:
    """The main file (if any), everything it imports, and the prelude, resolved the way the
    frontend resolves imports (``dsl/imports.py``: next to the importing file, then in
    ``search_paths`` unless the importer is a stdlib file, then in the stdlib).  Source text
    imports relative to ``filename``'s folder when one is given.  Used to key the kernel
    cache, so a user plugin's file is part of the key of every kernel importing it."""
    files: list[Path] = []
    seen: set[Path] = set()
    paths = [Path(p) for p in search_paths]
    stdlib = STDLIB.resolve()

    def visit(path: Path) -> None:
        path = path.resolve()
        if path in seen or not path.is_file():
            return
        seen.add(path)
        files.append(path)
        scan(path.read_text(errors="replace"), path.parent, path.is_relative_to(stdlib))

    def scan(text: str, folder: Path, from_stdlib: bool = False) -> None:
        for m in re.finditer(r"^\s*import\s+([A-Za-z_][\w.]*)\s*;", text, re.MULTILINE):
            rel = Path(*m.group(1).split(".")).with_suffix(".rdsl")
            for base in (folder, *([] if from_stdlib else paths), STDLIB):
                if (base / rel).is_file():
                    visit(base / rel)
                    break

    if is_path(source_or_path):
        visit(Path(source_or_path))
    else:
        named = filename is not None and not filename.startswith("<")
        scan(str(source_or_path), Path(filename).parent if named else Path.cwd())
    for name in PRELUDE:
        visit(STDLIB / f"{name}.rdsl")
    return files
