"""Golden IR of ``lift`` in the spectral and polarized variants.

For each program, ``golden/variants/NAME.VARIANT.expected`` holds its own functions as
``lift`` leaves them (after ``inline`` and ``optimize``, before the next ``optimize``), so a
change in how a variant represents ``Spectrum`` (four wavelengths, a Mueller matrix and the
entries known to be zero) shows as a diff.  The rgb variant is in ``golden/NAME.expected``
(``test_golden.py``).  Update with ``RDSL_UPDATE_GOLDEN=1`` (see ``tests/_golden.py``).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from _golden import GOLDEN, check_golden, user_functions
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.irparse import parse_module
from rdsl.compiler.printer import print_module

VARIANTS_DIR = GOLDEN / "variants"
# a Fresnel term and Spectrum arithmetic (variants/metal.rdsl); a struct holding a
# Spectrum and an `if const polarized` (spectrum.rdsl, also in test_golden.py)
PROGRAMS = [VARIANTS_DIR / "metal.rdsl", GOLDEN / "spectrum.rdsl"]
VARIANTS = ["spectral", "mono_polarized", "spectral_polarized"]
CASES = [(p, v) for p in PROGRAMS for v in VARIANTS]


def _lifted(path: Path, variant: str):
    module = frontend(path)
    run_passes(module, pipeline(Build.of("sse4", variant)), stop_after="lift")
    return module


@pytest.mark.parametrize("path,variant", CASES, ids=[f"{p.stem}-{v}" for p, v in CASES])
def test_lift_golden(path: Path, variant: str) -> None:
    module = _lifted(path, variant)
    got = f"// ----- {path.name} after lift, variant {variant} -----\n" + user_functions(module)
    check_golden(got, VARIANTS_DIR / f"{path.stem}.{variant}.expected")


@pytest.mark.parametrize("variant", VARIANTS)
def test_lifted_ir_round_trips(variant: str) -> None:
    text = print_module(_lifted(PROGRAMS[0], variant))
    assert print_module(parse_module(text)) == text
