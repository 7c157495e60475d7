"""Diagnostics: ``file:line:col: error: message``, the source line and a caret.

Every user-facing error in rdsl (frontend, passes, backends, runtime) is a
:class:`CompileError` carrying one or more :class:`Diagnostic`.  The CLI prints them and exits
with status 1; it never shows a Python traceback for a user's mistake.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .ir import Loc

# Source text of files seen by the frontend, so that any pass can quote the user's line.
_SOURCES: dict[str, str] = {}


def register_source(filename: str, text: str) -> None:
    """Remember ``text`` as the contents of ``filename`` for quoting in diagnostics."""
    _SOURCES[filename] = text


def source_line(filename: str, line: int) -> str | None:
    text = _SOURCES.get(filename)
    if text is None:
        try:
            text = Path(filename).read_text()
        except (OSError, UnicodeDecodeError):
            return None
        _SOURCES[filename] = text
    lines = text.splitlines()
    if 1 <= line <= len(lines):
        return lines[line - 1]
    return None


@dataclass
class Diagnostic:
    """One message attached to a source location."""

    loc: Loc | None
    message: str
    severity: str = "error"

    def format(self) -> str:
        if self.loc is None or self.loc.line <= 0:
            where = f"{self.loc.file}: " if self.loc and self.loc.file != "<unknown>" else ""
            return f"{where}{self.severity}: {self.message}"
        head = f"{self.loc}: {self.severity}: {self.message}"
        text = source_line(self.loc.file, self.loc.line)
        if text is None:
            return head
        col = max(self.loc.col, 1)
        # keep tabs so the caret lines up under the same glyphs
        pad = "".join(c if c == "\t" else " " for c in text[: col - 1])
        return f"{head}\n    {text}\n    {pad}^"


class CompileError(Exception):
    """A user-facing error.  ``str(err)`` is the formatted diagnostics."""

    def __init__(self, diagnostics: list[Diagnostic] | Diagnostic | str,
                 loc: Loc | None = None) -> None:
        if isinstance(diagnostics, str):
            diagnostics = [Diagnostic(loc, diagnostics)]
        elif isinstance(diagnostics, Diagnostic):
            diagnostics = [diagnostics]
        self.diagnostics = diagnostics
        super().__init__(self.format())

    def format(self) -> str:
        return "\n".join(d.format() for d in self.diagnostics)


def error(message: str, loc: Loc | None = None) -> CompileError:
    """Shorthand: ``raise error("bad thing", ins.loc)``."""
    return CompileError([Diagnostic(loc, message)])


def read_source_file(path: Path) -> str:
    """The text of a ``.rdsl`` file.  A file that cannot be read is an error naming it; one
    that is not UTF-8 is an error at its first bad byte's line and column (the column counts
    the characters before it on its line, as the parser's columns do)."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise CompileError(f"cannot read `{path}`: {e.strerror or e}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        start = data.rfind(b"\n", 0, e.start) + 1
        line = data.count(b"\n", 0, e.start) + 1
        col = len(data[start:e.start].decode("utf-8", errors="replace")) + 1
        _SOURCES[str(path)] = data.decode("utf-8", errors="replace")
        loc = Loc(str(path), line, col)
        raise CompileError(Diagnostic(loc, f"the file is not UTF-8 from here: byte 0x{data[e.start]:02x} "
                                           f"({e.reason})")) from None


class InternalError(Exception):
    """A bug in rdsl (not the user's fault), tagged with the pass that hit it
    (compiler/driver.py)."""
