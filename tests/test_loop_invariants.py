"""`optimize` replaces a loop-carried value that every iteration passes on unchanged by its
initial value (a path tracer's sampler kind and pixel key, carried through the bounces in
the sampler struct), so what depends on it folds: a constant one's dead branch goes, and
the slot itself is dropped.  The behaviour is the program's (the interpreter before and
after, bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest

from rdsl.compiler.driver import frontend, run_passes
from rdsl.compiler.interp import run_function
from rdsl.compiler.ir import Op
from rdsl.compiler.passes.inline import Inline
from rdsl.compiler.passes.optimize import Optimize
from rdsl.compiler.passes.scalarize import Scalarize

SRC = """
struct Gen { state: UInt, kind: Int, key: UInt }
fn next(g: Gen) -> (Gen, Float) {
    var u = 0.0;
    var s = g.state * 747796405u + 2891336453u;
    if g.kind == 3 {  // a costly other kind: its own loop
        var h = s ^ g.key;
        var k = 0;
        while k < 7 { h = (h ^ (h >> 13u)) * 0x5bd1e995u; k += 1; }
        u = Float(h >> 8u) * 5.9604645e-08;
    } else {
        u = Float(s >> 8u) * 5.9604645e-08;
    }
    return (Gen { state: s, kind: g.kind, key: g.key }, u);
}
fn walk(x: Float, kind: Int, seed: UInt) -> Float {
    var g = Gen { state: seed, kind: kind, key: seed * 3u };
    var acc = x;
    var n = 0;
    while acc < 10.0 && n < 50 {
        let (g2, u) = next(g);
        g = g2;
        acc += u;
        n += 1;
    }
    return acc + Float(n);
}
fn kernel(x: Float, seed: UInt) -> Float { return walk(x, 1, seed); }
fn kernel3(x: Float, seed: UInt) -> Float { return walk(x, 3, seed); }
"""


def _compiled():
    # as in the pipeline: the sampler struct's fields are carried apart after scalarize; the
    # optimize after it finds them unchanged, the next one folds what they decide
    m = frontend(SRC)
    run_passes(m, [Inline(), Optimize(), Scalarize(), Optimize(), Optimize()])
    return m


def _loops(fn) -> list:
    return [i for i in fn.walk() if i.op is Op.LOOP]


def test_a_constant_carried_through_a_loop_folds_its_branch():
    m = _compiled()
    # kind 1: the kind-3 branch (and its inner loop) is gone, and so are the kind and key
    # slots of the walk's loop (state, acc, n and the exit flag remain)
    loops = _loops(m.functions["kernel"])
    assert len(loops) == 1
    assert len(loops[0].results) <= 4, [a.name for a in loops[0].regions[0].args]
    # kind 3: its branch stays, the inner loop with it
    assert len(_loops(m.functions["kernel3"])) == 2


@pytest.mark.parametrize("x,seed", [(0.0, 1), (3.5, 77), (9.9, 123456789), (-4.0, 0),
                                    (np.inf, 5), (np.nan, 9)])
def test_folding_keeps_the_behaviour(x, seed):
    before = frontend(SRC)
    after = _compiled()
    for name in ("kernel", "kernel3"):
        args = [np.float32(x), np.uint32(seed)]
        want = run_function(before, name, args)
        got = run_function(after, name, args)
        np.testing.assert_array_equal(np.float32(got[0]), np.float32(want[0]))
