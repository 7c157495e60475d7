"""The ``tape_stores`` pass (compiler/passes/tape_stores.py): an adjoint kernel's primal
stores only the tape values that its sweep loads.  Checked on the IR around the pass (a
loop whose carried counter and inactive value no sweep reads: their stores go, every other
store stays, no load changes) and on the kernels: with the tape (and the pass) the
gradients are those of recomputation without a tape, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np

import rdsl
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import Op
from rdsl.compiler.passes.ad_checkpoint import TAPE_LANES, TAPE_VALUE
from rdsl.compiler.passes.tape_stores import TapeStores

# `junk` and `i` are carried but inactive: the sweep reads `t` (through p * t) and p
SRC = """
fn k(x: Float, PRM: [Float]) -> Float {
    let p = PRM[0];
    var s = 0.0;
    var t = x;
    var junk = 1.0;
    var i = 0;
    while i < 5 {
        s += p * t * t;
        junk = junk * 0.5 + t;
        t = t * 0.9 + 0.1;
        i += 1;
    }
    return s + junk * 0.0;
}
"""
BUILD = dataclasses.replace(rdsl.Build.of("host", "rgb", ad="reverse"), tape=8)


def _tape(fn, op):
    return [i.attrs[TAPE_VALUE] for i in fn.walk() if i.op is op and TAPE_VALUE in i.attrs]


def test_only_the_values_a_sweep_loads_are_stored():
    module = frontend(SRC, "k.rdsl")
    passes = pipeline(BUILD)
    at = next(k for k, p in enumerate(passes) if isinstance(p, TapeStores))
    run_passes(module, passes[:at], verify="ends")
    fn = module.functions["k"]
    stored, loaded = _tape(fn, Op.STORE), _tape(fn, Op.LOAD)
    assert set(stored) - set(loaded), "the premise: some stored values are never loaded"
    run_passes(module, [passes[at]], verify=True)
    assert set(_tape(fn, Op.STORE)) == set(stored) & set(loaded)
    assert sorted(_tape(fn, Op.LOAD)) == sorted(loaded)


def test_gradients_with_the_tape_are_those_without():
    x = np.linspace(-0.5, 2.0, 37).astype(np.float32)
    prm = np.array([0.7], np.float32)
    a = np.random.default_rng(4).standard_normal(x.size).astype(np.float32)
    i = np.arange(x.size, dtype=np.int32)
    out = {}
    for cap in (0, 8):
        k = rdsl.jit(SRC, build=dataclasses.replace(BUILD, tape=cap)).k
        floats = [p.get("tape_floats") for p in k.info["params"] if p["name"] == "ad_tape"]
        blocks = -(-x.size // TAPE_LANES)
        extra = [np.zeros(blocks * TAPE_LANES * floats[0], np.float32),
                 (i // TAPE_LANES) * TAPE_LANES * floats[0] + i % TAPE_LANES] if floats else []
        grad = np.zeros(x.size, np.float32)
        out[cap] = (*k(x, prm, a, grad, i, *extra), grad)
    for want, got in zip(out[0], out[8]):
        np.testing.assert_array_equal(got, want)
    # and the gradient is the analytic one: d/dp sum_k a * p t_k^2 = sum_k a t_k^2
    t, want = x.astype(np.float64), 0.0
    for _ in range(5):
        want = want + a * t * t
        t = t * np.float32(0.9) + np.float32(0.1)
    np.testing.assert_allclose(out[8][-1].sum(), want.sum(), rtol=1e-4)
