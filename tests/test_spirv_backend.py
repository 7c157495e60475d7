"""The SPIR-V backend (``--target spirv``): GLSL compute shaders compiled by
``glslangValidator``, linked by ``spirv-link``, checked by ``spirv-val`` and run on Vulkan
(lavapipe here).

Tolerance: none.  On lavapipe every comparison below is bit for bit: the shaders declare their
floats ``precise`` (no FMA contraction) and lavapipe's sqrt and division are exactly rounded,
so the compiler corpus agrees with the interpreter and the stdlib BSDFs with the LLVM avx2
build exactly.  One documented exception: lavapipe (Mesa's llvmpipe) stops a shader's loops
after 65535 trips round all its loops together, so a kernel that loops longer per element (roughplastic
compiled without a scene computes its coating integrals, 32 x 32 quadrature nodes with an
inner Newton loop, at every call) gives wrong values there; ``test_loop_cap`` pins the limit."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.backends.spirv_build import build_spirv_library
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import compile_kernels
from test_c_backend import _call_raw, _random_inputs, assert_bitwise
from test_cli import assert_user_error
from test_cli import rdsl as rdsl_cli
from test_differential import CASES, CORPUS, check_case, interp_modules  # noqa: F401

ROOT = Path(rdsl.__file__).resolve().parent
TOOLS = {"glslangValidator": "glslang-tools", "spirv-link": "spirv-tools",
         "spirv-val": "spirv-tools"}
_MISSING = [f"{t} (Debian's {p})" for t, p in TOOLS.items() if shutil.which(t) is None]
needs_tools = pytest.mark.skipif(bool(_MISSING), reason="missing " + ", ".join(_MISSING))


def _vulkan_reason() -> str | None:
    if _MISSING:
        return "missing " + ", ".join(_MISSING)
    try:
        from rdsl.runtime.vulkan import Device

        Device.get()
    except Exception as e:  # noqa: BLE001 - VulkanUnavailable, or any error of a driver
        return str(e)
    return None


_VK = _vulkan_reason()
needs_vulkan = pytest.mark.skipif(_VK is not None, reason=f"no Vulkan: {_VK}")


def _device_name() -> str:
    from rdsl.runtime.vulkan import Device

    return Device.get().name


# -- the compiler corpus against the interpreter ------------------------------------------


@pytest.fixture(scope="module")
def spirv_compiled():
    return {(f.stem, "spirv"): rdsl.jit(f, target="spirv") for f in CORPUS.glob("*.rdsl")}


@needs_vulkan
@pytest.mark.xdist_group("corpus-spirv")  # one worker: the module fixtures build once
@pytest.mark.parametrize("case", sorted(CASES), ids=lambda c: f"{c[0]}.{c[1]}")
def test_corpus_matches_interpreter(case, interp_modules, spirv_compiled):  # noqa: F811
    check_case(case, interp_modules[case[0]], spirv_compiled)


# -- the stdlib BSDFs and the GGX benchmark kernel against LLVM ---------------------------

BSDFS = sorted(p for p in (ROOT / "stdlib" / "bsdf").glob("*.rdsl")
               if re.search(r"^bsdf \w+", p.read_text(), re.MULTILINE))
KERNELS = [*BSDFS, ROOT / "bench" / "ggx_kernel.rdsl"]


def _run_spirv(mod, kernel: dict, inputs: dict, n: int) -> list[np.ndarray]:
    """Call a kernel's shader with the flat arguments of the C view (as ``_call_raw``)."""
    from rdsl.runtime.spirv_module import HOST_NP

    values = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in inputs.items()}
    outs = [a for a in kernel["args"] if a["kind"] == "output"]
    for a in outs:
        values[a["name"]] = np.zeros(n, HOST_NP[a["dtype"]])
    mod._lib.entries[kernel["symbol"]].run(n, values, None)
    return [values[a["name"]] for a in outs]


@needs_vulkan
@pytest.mark.parametrize("path", KERNELS, ids=lambda p: p.stem)
def test_kernels_match_llvm(path: Path):
    if path.stem == "roughplastic" and _device_name().startswith("llvmpipe"):
        pytest.skip("lavapipe stops loops after ~65535 iterations per invocation; "
                    "roughplastic's per-call coating integrals loop longer (see test_loop_cap)")
    mod = rdsl.jit(path, target="spirv")
    ref = rdsl.jit(path, target="avx2" if "avx2" in _host() else "scalar")
    kernels = [k for k in ref.manifest["kernels"]
               if path.parent.name != "bsdf" or k["name"].rsplit(".", 1)[-1]
               in ("eval", "pdf", "sample")]
    if path.parent.name == "bsdf":
        assert len(kernels) == 3, [k["name"] for k in ref.manifest["kernels"]]
    rng = np.random.default_rng(5)
    n = 257  # not a multiple of the work group size (64): the last group is partial
    nonzero = 0
    for k in kernels:
        inputs = _random_inputs(k, n, rng)
        want = _call_raw(ref._lib, k, {a: (v.copy() if isinstance(v, np.ndarray) else v)
                                       for a, v in inputs.items()}, n)
        nonzero += assert_bitwise(k, _run_spirv(mod, k, inputs, n), want)
    assert nonzero > 0, "every output is 0 (a vacuous check)"


def _host() -> str:
    from rdsl.compiler.targets import host_target

    return host_target().name


# -- 64-bit integers (PCG32), loops, masks and strided arrays through the Kernel API ------

PCG = """
import pcg32;
fn draw(seed: UInt64, k: Int) -> Float {
    var rng = pcg32_seed(seed, 54ul);
    var u = 0.0;
    for i in 0..k { let (r1, x) = pcg32_next_float(rng); rng = r1; u = x; }
    return u;
}
fn mix(a: UInt64, b: UInt64, s: UInt) -> (UInt64, UInt, Float, Int) {
    return (a * b + (a >> 7ul) ^ (b << UInt64(s)), UInt(a % (b + 1ul)), Float(a),
            Int(a / (b | 1ul)));
}
"""


@needs_vulkan
def test_uint64_and_pcg32_bit_exact():
    mod, ref = rdsl.jit(PCG, target="spirv"), rdsl.jit(PCG, target="scalar")
    seed = np.arange(1000, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    k = (np.arange(1000) % 17 + 1).astype(np.int32)
    got = mod["draw"](seed, k)
    assert np.array_equal(got, ref["draw"](seed, k)) and np.unique(got).size > 900
    rng = np.random.default_rng(0)
    a = rng.integers(0, 2**64 - 1, 1000, dtype=np.uint64)
    b = rng.integers(0, 2**64 - 1, 1000, dtype=np.uint64)
    s = rng.integers(0, 64, 1000).astype(np.uint32)
    for g, w in zip(mod["mix"](a, b, s), ref["mix"](a, b, s)):
        assert np.array_equal(g, w)


@needs_vulkan
def test_float_rem_is_fmodf_bit_for_bit():
    """GLSL has no fmod (its ``mod`` floors); the shader's is musl's exact integer one."""
    mod = rdsl.jit("fn r(a: Float, b: Float) -> Float { return a % b; }", target="spirv")
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, 2**32, size=(2, 20000), dtype=np.uint64).astype(np.uint32)
    special = np.array([0.0, -0.0, 1.0, -3.0, 1e-45, -1e-38, np.inf, -np.inf, np.nan, 5.5,
                        1e30, 3.4e38], np.float32)
    sa, sb = np.meshgrid(special, special)
    a = np.concatenate([a.view(np.float32), sa.ravel(),
                        rng.uniform(-99, 99, 5000).astype(np.float32)])
    b = np.concatenate([b.view(np.float32), sb.ravel(),
                        rng.uniform(-3, 3, 5000).astype(np.float32)])
    with np.errstate(all="ignore"):
        want = np.fmod(a, b)  # C's fmodf
    assert_bitwise({"name": "r", "args": [{"name": "ret", "kind": "output"}]},
                   [mod["r"](a, b)], [want])


LOOPS = """
fn cube(n: Int) -> Float {
    var acc = 0.0;
    for i in 0..n { for j in 0..n { for k in 0..n { acc += 1.0; } } }
    return acc;
}
fn shade(a: Float, b: Float, k: Int, flag: Bool) -> Float {
    if flag { return a * b + Float(k); }
    return a - b;
}
"""


@needs_vulkan
def test_loop_cap():
    mod = rdsl.jit(LOOPS, target="spirv")
    # 39^3 + 39^2 + 39 = 60879 trips of the three loops together: below the cap
    n = np.array([1, 8, 17, 33, 39], np.int32)
    assert np.array_equal(mod["cube"](n), (n.astype(np.float32) ** 3))
    if _device_name().startswith("llvmpipe"):  # the driver's limit, pinned: 64^3 stops early
        assert mod["cube"](np.array([64], np.int32))[0] < 64.0 ** 3


@needs_vulkan
def test_kernel_api_masks_strides_out():
    mod = rdsl.jit(LOOPS, target="spirv")
    rows = np.zeros(300, [("a", np.float32), ("k", np.int32), ("b", np.float32)])
    rows["a"] = np.linspace(-3, 3, 300)
    rows["b"] = np.linspace(2, -1, 300)
    rows["k"] = np.arange(300) % 7 - 3
    flag = np.arange(300) % 3 != 0
    mask = np.arange(300) % 5 != 2
    out = np.full(300, -7.0, np.float32)
    mod["shade"](rows["a"], rows["b"][::-1][::-1], rows["k"], flag, mask=mask, out=out)
    a, b, k = rows["a"], rows["b"], rows["k"].astype(np.float32)
    want = np.where(flag, a * b + k, a - b).astype(np.float32)
    assert np.array_equal(out, np.where(mask, want, np.float32(-7.0)))
    assert np.array_equal(mod["shade"](rows["a"], 0.5, 2, True), rows["a"] * 0.5 + 2)


# -- every stdlib plugin through spirv-val -------------------------------------------------

PLUGINS = sorted(p for d in ("bsdf", "emitter", "texture", "integrator")
                 for p in (ROOT / "stdlib" / d).glob("*.rdsl"))


@needs_tools
@pytest.mark.parametrize("path", PLUGINS, ids=lambda p: f"{p.parent.name}.{p.stem}")
def test_plugin_passes_spirv_val(path: Path, tmp_path: Path):
    build = Build.of("spirv")
    try:
        module, _ = compile_kernels(path, build)
        paths = build_spirv_library(module, build.target, tmp_path, path.stem)
    except CompileError as e:
        if "cannot trace rays" in str(e):  # the one thing beyond the target, and said so
            return
        # anything else is no target's: an integrator needs a scene's buffers to compile
        with pytest.raises(CompileError) as llvm:
            compile_kernels(path, Build.of("scalar"))
        assert str(llvm.value) == str(e)
        return
    if "spv" not in paths:  # a library of functions only: no kernel, no shader
        assert json.loads(paths["manifest"].read_text())["kernels"] == []
        return
    assert paths["spv"].read_bytes()[:4] == b"\x03\x02\x23\x07"  # the SPIR-V magic
    assert "#version 450" in paths["comp"].read_text()


# -- the Cornell box through the BVH written in rdsl ------------------------------------

BVH = ROOT / "stdlib" / "render" / "bvh.rdsl"
CBOX = ROOT.parent / "shared" / "scenes" / "cbox" / "cbox.xml"


@needs_vulkan
@pytest.mark.skipif(not BVH.is_file(), reason="needs stdlib/render/bvh.rdsl (the rdsl BVH)")
@pytest.mark.skipif(not CBOX.is_file(), reason=f"no scene at {CBOX}")
def test_cbox_renders_as_llvm_with_the_bvh(tmp_path: Path):
    """The render kernel, traversal included, on Vulkan: the LLVM build's image through the
    same BVH, bit for bit (that one is checked against Mitsuba and Embree elsewhere)."""
    scene = rdsl.load_scene(CBOX, target="spirv", accel="bvh", res=24)
    got = scene.render(spp=2, seed=3)
    want = rdsl.load_scene(CBOX, target="avx2" if "avx2" in _host() else "scalar",
                           accel="bvh", res=24).render(spp=2, seed=3)
    assert got.max() > 0 and np.array_equal(got, want)
    r = rdsl_cli("render", str(CBOX), "--target", "spirv", "--spp", "1", "-D", "res=16",
                 "--quiet", "-o", str(tmp_path / "cb.exr"))
    assert r.returncode == 0 and (tmp_path / "cb.exr").is_file(), r.stderr


# -- the command line and bad input --------------------------------------------------------


@needs_vulkan
def test_cli_compile_and_load(tmp_path: Path):
    src = tmp_path / "loops.rdsl"
    src.write_text(LOOPS)
    r = rdsl_cli("compile", str(src), "--target", "spirv", "-o", str(tmp_path / "out" / "k"))
    assert r.returncode == 0, r.stderr
    for ext in (".comp", ".spv", ".json"):
        assert (tmp_path / "out" / f"k{ext}").is_file(), ext
    mod = rdsl.load(tmp_path / "out" / "k.spv")
    assert (mod.target, mod.width, mod.manifest["backend"]) == ("spirv", 1, "spirv")
    assert np.array_equal(mod["cube"](np.array([3, 5], np.int32)), [27.0, 125.0])


def test_bad_input(tmp_path: Path, monkeypatch):
    src = tmp_path / "loops.rdsl"
    src.write_text(LOOPS)
    assert_user_error(rdsl_cli("compile", str(src), "--target", "spirv", "--width", "8"),
                      "target `spirv` runs one element per shader invocation")
    if CBOX.is_file():  # shaders cannot call Embree
        assert_user_error(rdsl_cli("render", str(CBOX), "--target", "spirv", "--accel",
                                   "embree", "-D", "res=8", "--spp", "1", "--quiet", "-o",
                                   str(tmp_path / "e.exr")), "target `spirv`", "--accel bvh")
    rays = tmp_path / "rays.rdsl"
    rays.write_text("fn blocked(o: Vec3, d: Vec3) -> Bool {\n"
                    "    return occluded(Ray { o: o, d: d, tmax: 1.0 });\n}\n")
    assert_user_error(rdsl_cli("compile", str(rays), "--target", "spirv"),
                      "rays.rdsl:2:", "`occluded`", "cannot trace rays")
    build = Build.of("spirv")
    module, _ = compile_kernels(LOOPS, build)
    monkeypatch.setenv("PATH", str(tmp_path))  # no glslangValidator there
    with pytest.raises(CompileError, match=r"`glslangValidator`.*glslang-tools"):
        build_spirv_library(module, build.target, tmp_path, "k")
