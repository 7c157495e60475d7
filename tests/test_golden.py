"""Golden IR tests: the IR printed after each pass, compared with expected text.

Each ``golden/NAME.rdsl`` has ``golden/NAME.expected`` holding the IR after lowering and
after every pass of the pipeline (variant rgb, width 4).  Regenerate after an intended
change with ``RDSL_UPDATE_GOLDEN=1 pytest tests/test_golden.py`` and review the diff.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import pytest
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import UNKNOWN_LOC
from rdsl.compiler.irparse import parse_module
from rdsl.compiler.printer import print_function, print_module

GOLDEN = Path(__file__).parent / "golden"
PROGRAMS = sorted(GOLDEN.glob("*.rdsl"))


def _user_functions(module) -> str:
    """The functions of the program's own file (the prelude and imports are left out)."""
    return "".join(print_function(f, locs=False) + "\n" for f in module.functions.values()
                   if f.attrs.get("export"))


def _stages(path: Path) -> str:
    module = frontend(path)
    out = io.StringIO()
    out.write("// ----- after lower -----\n" + _user_functions(module))
    for p in pipeline(Build.of("sse4", "rgb")):
        run_passes(module, [p], verify=True)
        out.write(f"// ----- after {p.name} -----\n" + _user_functions(module))
    return out.getvalue()


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.stem)
def test_golden(path: Path):
    got = _stages(path)
    expected = path.with_suffix(".expected")
    if os.environ.get("RDSL_UPDATE_GOLDEN") or not expected.exists():
        expected.write_text(got)
        if not os.environ.get("RDSL_UPDATE_GOLDEN"):
            pytest.fail(f"{expected.name} was missing and has been written; review it")
    assert got == expected.read_text()


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.stem)
def test_every_instruction_has_a_location(path: Path):
    module = frontend(path)
    for p in [None] + pipeline(Build.of("sse4", "rgb")):
        if p is not None:
            run_passes(module, [p], verify=False)
        for fn in module.functions.values():
            for ins in fn.walk():
                assert ins.loc != UNKNOWN_LOC and ins.loc.line > 0, \
                    f"{fn.name}: `{ins.op.value}` has no location after {p and p.name}"


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.stem)
def test_textual_ir_round_trips_after_every_pass(path: Path):
    module = frontend(path)
    for p in pipeline(Build.of("sse4", "rgb")):
        run_passes(module, [p], verify=False)
        text = print_module(module)
        assert print_module(parse_module(text)) == text, f"after {p.name}"
