"""`evaluate`: a pure call whose arguments are constants after specialization is run once by
the compiler and replaced by its value; a call with a varying argument is kept."""

from __future__ import annotations

import math

import numpy as np

import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import Op
from rdsl.core.scene_spec import Instance, SceneSpec

# `series(x, n)`: the partial sum of exp(x) = sum x^k / k!, a loop the optimizer cannot fold
SERIES = """
fn series(x: Float, n: Int) -> Float {
    var term = 1.0;
    var acc = 1.0;
    for k in 1..n {
        term = term * x / Float(k);
        acc += term;
    }
    return acc;
}
"""
SRC = SERIES + """
fn folded(y: Float) -> Float {
    return y * series(0.5, 12);
}
fn kept(y: Float) -> Float {
    return series(y, 12);
}
"""


def _calls_and_consts(fn) -> tuple[list[str], list[float]]:
    calls = [i.attrs["callee"] for i in fn.walk() if i.op is Op.CALL]
    consts = [i.attrs["value"] for i in fn.walk() if i.op is Op.CONST]
    return calls, consts


def test_constant_call_is_evaluated_and_varying_call_kept():
    m = frontend(SRC)
    passes = pipeline(Build.of("scalar", "rgb"))
    names = [p.name for p in passes]
    stop = names.index("evaluate")
    run_passes(m, passes[:stop + 1])
    calls, consts = _calls_and_consts(m.functions["folded"])
    assert calls == []  # evaluated at compile time
    want = sum(0.5 ** k / math.factorial(k) for k in range(12))
    assert any(abs(c - want) < 1e-6 for c in consts if isinstance(c, float))
    calls, _ = _calls_and_consts(m.functions["kept"])
    assert calls == ["series"]  # y varies: the call stays for the second inline


def test_evaluated_kernels_compute_the_same_values():
    mod = rdsl.jit(SRC, target="scalar")
    y = np.linspace(-1.0, 2.0, 7, dtype=np.float32)
    want = np.array([sum(float(v) ** k / math.factorial(k) for k in range(12)) for v in y])
    np.testing.assert_allclose(mod.kept(y), want, rtol=2e-6)
    np.testing.assert_allclose(mod.folded(y), y * math.exp(0.5), rtol=1e-6, atol=1e-7)


PLUGIN_SRC = "import render.scene;\n" + SERIES + """
bsdf glow {
    param strength: Float = 1.0;
    fn eval(si: Surface, wo: Vec3) -> Spectrum { return Spectrum(series(strength, 16) * wo.z); }
    fn pdf(si: Surface, wo: Vec3) -> Float { return 0.0; }
    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {
        return BsdfSample { wo: si.wi, pdf: 0.0, eta: 1.0, weight: Spectrum(0.0), delta: false };
    }
}
fn shade(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
"""


def test_scene_constants_reach_the_evaluator():
    """After specialization a plugin's parameters are constants: a loop over them runs once,
    in the compiler; the kernel computes exp(strength) * wo.z from the folded value."""
    scene = SceneSpec(bsdfs=[Instance("glow", {"strength": 0.75})])
    report: list[str] = []
    m = frontend(PLUGIN_SRC)
    passes = pipeline(Build.of("scalar", "rgb"), scene, report)
    stop = [p.name for p in passes].index("evaluate")
    run_passes(m, passes[:stop + 1])
    assert "evaluate: 1 call(s) evaluated at compile time" in report, report
    assert not any(i.op is Op.LOOP for i in m.functions["shade"].walk())
    mod = rdsl.jit(PLUGIN_SRC, target="scalar", scene=scene)
    n = 5
    wo = np.tile(np.array([0.0, 0.6, 0.8], np.float32), (n, 1))
    z = np.zeros((n, 3), np.float32)
    si = {"p": z, "n": z, "sh_n": z, "uv": np.zeros((n, 2), np.float32), "wi": wo,
          "t": np.ones(n, np.float32), "valid": np.ones(n, bool)}
    got = np.asarray(mod.shade(np.zeros(n, np.int32), si, wo, np.zeros(3, np.float32)))
    np.testing.assert_allclose(got, math.exp(0.75) * 0.8, rtol=1e-6)
