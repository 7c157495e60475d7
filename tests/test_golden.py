"""Golden IR tests: the IR printed after each pass, compared with expected text.

Each ``golden/NAME.rdsl`` has ``golden/NAME.expected`` holding the IR after lowering and
after every pass of the pipeline (variant rgb, width 4).  Regenerate after an intended
change with ``RDSL_UPDATE_GOLDEN=1 pytest tests/test_golden.py`` and review the diff.
The other variants, specialization and diagnostics have their own golden tests
(``test_golden_variants.py``, ``test_golden_specialize.py``, ``test_golden_diagnostics.py``).
"""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from _golden import GOLDEN, check_golden, user_functions
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import UNKNOWN_LOC
from rdsl.compiler.irparse import parse_module
from rdsl.compiler.printer import print_module

PROGRAMS = sorted(GOLDEN.glob("*.rdsl"))


def _stages(path: Path) -> str:
    module = frontend(path)
    out = io.StringIO()
    out.write("// ----- after lower -----\n" + user_functions(module))
    for p in pipeline(Build.of("sse4", "rgb")):
        run_passes(module, [p], verify=True)
        out.write(f"// ----- after {p.name} -----\n" + user_functions(module))
    return out.getvalue()


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.stem)
def test_golden(path: Path):
    check_golden(_stages(path), path.with_suffix(".expected"))


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
