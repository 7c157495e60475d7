"""The builtin table (``compiler/builtins.py``) is the one list of builtins: the checker
accepts exactly its names, every entry lowers to what it declares, and every builtin that
computes something evaluates to the same bits in the interpreter and in compiled code."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.compiler.builtins import BUILTINS, F32_INTRINSICS
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.interp import run_function
from rdsl.compiler.ir import Op
from rdsl.dsl.builtins import BUILTIN_FNS

# per builtin: the variant its sample runs in and the body of `fn k_<name>(x: Float,
# y: Float, i: Int) -> <type>` (the type first, then the body)
SAMPLES: dict[str, tuple[str, str, str]] = {
    "sqrt": ("rgb", "Float", "return sqrt(x);"),
    "derivative": ("rgb", "Float", "return derivative(x * y) + x;"),
    "detach": ("rgb", "Float", "return detach(x) * y;"),
    "floor": ("rgb", "Vec2", "return floor(Vec2(x, y));"),
    "ceil": ("rgb", "Float", "return ceil(y);"),
    "abs": ("rgb", "Float", "return abs(x) + Float(abs(i));"),
    "min": ("rgb", "Float", "return min(x, y) + Float(min(i, 7));"),
    "max": ("rgb", "Float", "return max(x, y) + Float(max(i, 7));"),
    "select": ("rgb", "Float", "return select(x < y, x, y * 2.0);"),
    "bits": ("rgb", "UInt", "return bits(x);"),
    "from_bits": ("rgb", "Float", "return from_bits(UInt(i) * 2654435761u);"),
    "Float": ("rgb", "Float", "return Float(i) + Float(true);"),
    "Int": ("rgb", "Int", "return Int(x) + Int(i);"),
    "UInt": ("rgb", "UInt", "return UInt(y);"),
    "UInt64": ("rgb", "UInt64", "return UInt64(x) + UInt64(i);"),
    "Bool": ("rgb", "Float", "return select(Bool(i), x, y);"),
    "Vec2": ("rgb", "Vec2", "return Vec2(x, y) + Vec2(y);"),
    "Vec3": ("rgb", "Vec3", "return Vec3(Vec2(x, y), 1.5);"),
    "Vec4": ("rgb", "Vec4", "return Vec4(x, Vec2(y, x), 2);"),
    "Mat3": ("rgb", "Mat3", "return Mat3(Vec3(x), Vec3(y), Vec3(x, y, 1.0));"),
    "Mat4": ("rgb", "Mat4", "return Mat4(Vec4(x), Vec4(y), Vec4(1.0), Vec4(x, y, x, y));"),
    "Spectrum": ("rgb", "Spectrum", "return Spectrum(x, y, 0.5) + Spectrum(y);"),
    "illuminant": ("rgb", "Spectrum", "return illuminant(x, y, 0.5, 2.0);"),
    "mean": ("rgb", "Float", "return mean(Spectrum(x, y, 0.25));"),
    "max_value": ("rgb", "Float", "return max_value(Spectrum(x, y, 0.25));"),
    "set_wavelengths": ("spectral", "Float",
                        "set_wavelengths(Spectrum(500.0 + x, 550.0, 600.0 + y, 700.0));\n"
                        "    return mean(Spectrum(0.25, 0.5, 0.75));"),
    "wavelengths": ("spectral", "Spectrum",
                    "set_wavelengths(Spectrum(400.0 + x, 500.0, 600.0, 700.0 + y));\n"
                    "    return wavelengths();"),
    "to_srgb": ("spectral", "Vec3",
                "set_wavelengths(Spectrum(450.0 + x, 500.0, 600.0 + y, 650.0));\n"
                "    return to_srgb(Spectrum(x, y, 1.0, 2.0));"),
    "Unpolarized": ("mono_polarized", "Unpolarized", "return Unpolarized(x) * Unpolarized(y);"),
    "unpolarized": ("mono_polarized", "Unpolarized", "return unpolarized(Spectrum(x) * y);"),
    "depolarizer": ("mono_polarized", "Unpolarized",
                    "return unpolarized(depolarizer(Unpolarized(x)) * Spectrum(y));"),
    "mueller": ("mono_polarized", "Unpolarized",
                "let u = Unpolarized(x);\n    let v = Unpolarized(y);\n"
                "    let m = mueller(u, v, u, v, v, u, v, u, u, u, v, v, v, v, u, u);\n"
                "    return unpolarized(m * m);"),
    "mueller_entry": ("mono_polarized", "Unpolarized",
                      "let u = Unpolarized(x);\n    let v = Unpolarized(y);\n"
                      "    let m = mueller(u, v, u, v, v, u, v, u, u, u, v, v, v, v, u, u);\n"
                      "    return mueller_entry(m, 2, 3) + mueller_entry(m * m, 1, 0);"),
    # uniform across these inputs (no lane's y > 1e31, every lane's |x| < 1e30), so a lone
    # lane (the interpreter) agrees with a vector of them
    "any_lane": ("rgb", "Float", "return select(any_lane(y > 1e31), x, y) "
                 "+ select(any_lane(abs(x) < 1e30), 1.0, 0.0);"),
    # ray queries need a scene: checked and lowered only
    "trace": ("rgb", "Float", "let h = trace(Ray { o: Vec3(x), d: Vec3(0.0, 0.0, 1.0), "
              "tmax: y });\n    return h.t;"),
    "occluded": ("rgb", "Bool", "return occluded(Ray { o: Vec3(x), d: Vec3(0.0, 0.0, 1.0), "
                 "tmax: y });"),
}
NOT_RUN = {"trace", "occluded"}  # the interpreter does not trace rays
VARIANTS = sorted({v for v, _, _ in SAMPLES.values()})
XS = np.float32([0.25, -1.5, 3.75, 0.0, -0.0, 1e-3, 100.5, -7.0])
YS = np.float32([2.0, 0.5, -3.25, 1e30, 4.0, -0.0, 0.125, 9.5])
IS = np.int32([3, -4, 0, 2**31 - 1, -(2**31), 1, 7, -100])


def _source(variant: str, skip: set[str] = frozenset()) -> str:
    fns = [f"fn k_{name}(x: Float, y: Float, i: Int) -> {t} {{\n    {body}\n}}\n"
           for name, (v, t, body) in SAMPLES.items() if v == variant and name not in skip]
    return "import types;\n\n" + "\n".join(fns)


def test_the_checker_accepts_exactly_the_table():
    assert set(BUILTIN_FNS) == set(BUILTINS)
    assert set(SAMPLES) == set(BUILTINS), "every builtin needs a sample here"
    with pytest.raises(CompileError, match="unknown function `cbrt`"):
        frontend("fn k(x: Float) -> Float { return cbrt(x); }")


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_builtin_lowers_to_its_op(variant):
    module = frontend(_source(variant))
    for name, (v, _, _) in SAMPLES.items():
        if v != variant or not isinstance(BUILTINS[name].lower, Op):
            continue
        ops = {ins.op for ins in module.functions[f"k_{name}"].walk()}
        assert BUILTINS[name].lower in ops, name


def test_math_intrinsics_are_elementwise_ops():
    for op in F32_INTRINSICS:
        assert any(b.lower is op for b in BUILTINS.values()), op


def _bits(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype != np.float32:
        return a
    return np.where(np.isnan(a), np.float32(np.nan), a).view(np.uint32)


def _flat(v) -> list:
    if isinstance(v, tuple):
        return [x for c in v for x in _flat(c)]
    return [v]


@pytest.mark.parametrize("target", ["scalar", "host"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_interpreter_and_compiled_code_agree(variant, target):
    src = _source(variant, NOT_RUN)
    module = frontend(src)
    run_passes(module, pipeline(Build.of("scalar", variant)), stop_after="scalarize")
    kmod = rdsl.jit(src, target=target, variant=variant)
    for name, (v, _, _) in SAMPLES.items():
        if v != variant or name in NOT_RUN:
            continue
        fn = f"k_{name}"
        got = np.asarray(kmod[fn](XS, YS, IS, threads=1)).reshape(len(XS), -1)
        want = np.array([[np.asarray(c).astype(got.dtype) for c in
                          _flat(tuple(run_function(module, fn, [x, y, i])))]
                         for x, y, i in zip(XS, YS, IS)]).reshape(len(XS), -1)
        assert np.array_equal(_bits(got), _bits(want)), f"{name}: {got} != {want}"
