"""Golden diagnostics: each ``golden/diagnostics/NAME.rdsl`` is a program with one mistake,
and ``NAME.expected`` is exactly what rdsl prints for it: ``file:line:col: error: message``,
the source line, and a caret under the column.

The programs run through the whole pipeline (rgb, width 4), so a diagnostic raised by a pass
(``mueller_in_rgb``: ``lift``) is checked like one from the parser or the type checker.
``tests/test_diagnostics.py`` checks many more messages by substring and position.  Update
with ``RDSL_UPDATE_GOLDEN=1`` (see ``tests/_golden.py``).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _golden import GOLDEN, check_golden
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes

DIAGNOSTICS = GOLDEN / "diagnostics"
PROGRAMS = sorted(DIAGNOSTICS.glob("*.rdsl"))


def _diagnostic(path: Path) -> str:
    # the file's name alone, so that the text does not depend on where the checkout is
    with pytest.raises(CompileError) as info:
        module = frontend(path.read_text(), filename=path.name)
        run_passes(module, pipeline(Build.of("sse4", "rgb")))
    return str(info.value) + "\n"


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.stem)
def test_diagnostic_golden(path: Path) -> None:
    check_golden(_diagnostic(path), path.with_suffix(".expected"))


def test_the_four_kinds_are_covered() -> None:
    names = {p.stem for p in PROGRAMS}
    assert {"syntax_error", "type_error", "unknown_name", "plugin_interface"} <= names
