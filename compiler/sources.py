"""Which files a program is made of, found without importing the compiler (the kernel cache
hashes them before deciding whether to compile)."""

from __future__ import annotations

import re
from pathlib import Path

STDLIB = Path(__file__).resolve().parent.parent / "stdlib"
PRELUDE = ("types", "math")


def is_path(source_or_path: str | Path) -> bool:
    if isinstance(source_or_path, Path):
        return True
    s = str(source_or_path)
    return "\n" not in s and (s.endswith(".rdsl") or Path(s).is_file())


def source_files(source_or_path: str | Path) -> list[Path]:
    """The main file (if any), everything it imports, and the prelude, resolved the way the
    frontend resolves imports.  Used to key the kernel cache."""
    files: list[Path] = []
    seen: set[Path] = set()

    def visit(path: Path) -> None:
        path = path.resolve()
        if path in seen or not path.is_file():
            return
        seen.add(path)
        files.append(path)
        scan(path.read_text(errors="replace"), path.parent)

    def scan(text: str, folder: Path) -> None:
        for m in re.finditer(r"^\s*import\s+([A-Za-z_][\w.]*)\s*;", text, re.MULTILINE):
            rel = Path(*m.group(1).split(".")).with_suffix(".rdsl")
            for base in (folder, STDLIB):
                if (base / rel).is_file():
                    visit(base / rel)
                    break

    if is_path(source_or_path):
        visit(Path(source_or_path))
    else:
        scan(str(source_or_path), Path.cwd())
    for name in PRELUDE:
        visit(STDLIB / f"{name}.rdsl")
    return files
