"""The rdsl language frontend: parse, check and lower ``.rdsl`` source to the SSA IR.

* :func:`parse` -- source text to an :class:`ast.Program`;
* :func:`check` -- parse, resolve imports (plus the implicit ``stdlib/types.rdsl`` and
  ``stdlib/math.rdsl``) and type-check; returns a :class:`CheckedProgram`;
* :func:`compile_to_ir` -- parse, check and lower to an :class:`rdsl.compiler.ir.Module`.

Every user mistake raises :class:`rdsl.compiler.diagnostics.CompileError`.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from ..compiler import ir
from ..compiler.diagnostics import CompileError
from ..compiler.sources import read_source
from ..core.gcpause import gc_paused
from . import ast
from .checker import CheckedProgram, check_program
from .parser import parse

__all__ = ["CheckedProgram", "CompileError", "ast", "check", "compile_to_ir", "parse"]


def _source(path_or_source: str | Path, filename: str | None) -> tuple[str, str, Path | None]:
    text, path = read_source(path_or_source)
    return text, filename or (str(path) if path is not None else "<string>"), path


def check(path_or_source: str | Path, filename: str | None = None,
          search_paths: Iterable[str | Path] | None = None) -> CheckedProgram:
    """Parse and type-check a program (a file path or source text)."""
    text, name, path = _source(path_or_source, filename)
    try:
        return check_program(text, name, [Path(p) for p in (search_paths or [])], path)
    except RecursionError:
        raise CompileError("program too deeply nested", ir.Loc(name, 0, 0)) from None


def compile_to_ir(path_or_source: str | Path, filename: str | None = None,
                  search_paths: Iterable[str | Path] | None = None) -> ir.Module:
    """Parse, check and lower a program to an IR module (see docs/language.md); Python's
    cycle collector paused meanwhile, as in ``run_passes`` (compiler/driver.py)."""
    with gc_paused():
        return _compile_to_ir(path_or_source, filename, search_paths)


def _compile_to_ir(path_or_source: str | Path, filename: str | None,
                   search_paths: Iterable[str | Path] | None) -> ir.Module:
    from .lower import lower_program

    checked = check(path_or_source, filename, search_paths)
    try:
        return lower_program(checked)
    except RecursionError:
        raise CompileError("program too deeply nested",
                           ir.Loc(checked.main_file, 0, 0)) from None
    finally:
        checked.release()
