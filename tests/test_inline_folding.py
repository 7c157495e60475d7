"""`inline` folds what constant arguments decide while it copies a callee (a comparison or
boolean op of constants, an `if` on a constant: only its taken region), and the result
behaves as the program did (against the interpreter on the program before any pass)."""

from __future__ import annotations

import numpy as np
import pytest

from rdsl.compiler.driver import frontend, run_passes
from rdsl.compiler.interp import run_function
from rdsl.compiler.ir import Op
from rdsl.compiler.passes.inline import Inline

SRC = """
fn has_kind(k: Int) -> Bool { return k == 1 || k == 4; }
fn heavy(x: Float) -> Float {
    var a = x;
    for i in 0..8 { a = a * 0.5 + 1.0 / (1.0 + a * a); }
    return a;
}
fn light(x: Float) -> Float { return x + 1.0; }
fn pick(k: Int, x: Float) -> Float {
    if has_kind(k) && x > 0.0 { return heavy(x); }
    return light(x);
}
fn kernel(x: Float) -> Float { return pick(2, x) * 3.0 + pick(4, x); }
"""


def _loops(fn) -> int:
    return sum(1 for i in fn.walk() if i.op is Op.LOOP)


def test_a_constant_argument_copies_only_the_taken_branch():
    m = frontend(SRC)
    run_passes(m, [Inline()])
    assert _loops(m.functions["pick"]) == 1  # k unknown there: both branches stay
    # pick(2, x): has_kind(2) is false, so `heavy` is never copied; pick(4, x) keeps it
    assert _loops(m.functions["kernel"]) == 1
    assert not any(i.op is Op.CALL for i in m.functions["kernel"].walk())


@pytest.mark.parametrize("x", [-2.0, -0.0, 0.0, 0.25, 3.0, np.inf, np.nan])
def test_folding_keeps_the_behaviour(x):
    before = frontend(SRC)
    after = frontend(SRC)
    run_passes(after, [Inline()])
    want = run_function(before, "kernel", [np.float32(x)])
    got = run_function(after, "kernel", [np.float32(x)])
    np.testing.assert_array_equal(np.float32(got[0]), np.float32(want[0]))
