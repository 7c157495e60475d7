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


ONCE = """
fn twice_called(x: Float) -> Float { return x * x + 1.0; }
fn once_called(x: Float, k: Int) -> Float {
    var a = twice_called(x);
    if k == 3 { a = a * 2.0; } else { a = a - 1.0; }
    return a + twice_called(a);
}
fn kernel(x: Float) -> Float { return once_called(x, 3) * 0.5; }
"""


def _library(src: str):
    """``src`` lowered, with only `kernel` exported (the others as if imported)."""
    m = frontend(src)
    for name, fn in m.functions.items():
        if name != "kernel":
            fn.attrs.pop("export", None)
    return m


def test_a_function_called_once_is_moved_and_one_called_twice_copied():
    m = _library(ONCE)
    body_of_once = {id(i) for i in m.functions["once_called"].body.instrs}
    body_of_twice = {id(i) for i in m.functions["twice_called"].body.instrs}
    run_passes(m, [Inline()])
    kernel = {id(i) for i in m.functions["kernel"].walk()}
    assert set(m.functions) == {"kernel"}
    assert body_of_once - kernel  # the return is gone, and the folded `if`
    assert len(body_of_once & kernel) >= 3  # the rest are the same objects: moved
    assert not body_of_twice & kernel  # copied (twice), the original left behind
    assert not any(i.op is Op.IF for i in m.functions["kernel"].walk())  # k == 3 folded


@pytest.mark.parametrize("x", [-2.0, -0.0, 0.5, 3.0, np.inf, np.nan])
def test_moving_keeps_the_behaviour(x):
    before, after = frontend(ONCE), _library(ONCE)
    run_passes(after, [Inline()])
    want = run_function(before, "kernel", [np.float32(x)])
    got = run_function(after, "kernel", [np.float32(x)])
    np.testing.assert_array_equal(np.float32(got[0]), np.float32(want[0]))
