"""Target ``opencl`` (OpenCL C on PoCL, through pyopencl): the differential corpus against
the interpreter at widths 1, 8 and 16; every stdlib BSDF module's kernels (eval, pdf,
sample and the library functions) against the avx2 LLVM build on random inputs; a user
plugin kernel (bench/ggx_kernel.rdsl) through the CPU kernels' call interface (arrays,
broadcast scalars, masks, ``out=``, struct results); the command line; bad input.

Tolerance: none.  The program is built with exactly rounded division and sqrt and with
FP_CONTRACT OFF, and the IR has no other transcendental, so the OpenCL results must equal
the LLVM target's bit for bit (NaNs compared as NaN), as the C backend's do.

Skipped, with the reason, where pyopencl or an OpenCL platform is missing.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.targets import get_target, host_supports
from test_c_backend import (
    HOST_SRC,
    STDLIB_BSDFS,
    _bits,
    _call_raw,
    _random_inputs,
    assert_bitwise,
)
from test_cli import assert_user_error
from test_cli import rdsl as rdsl_cli
from test_differential import CASES, CORPUS, check_case, interp_modules  # noqa: F401


def _opencl_missing() -> str | None:
    from rdsl.runtime.opencl import OpenCLUnavailable, opencl_context

    try:
        opencl_context()
    except OpenCLUnavailable as e:
        return str(e)
    return None


MISSING = _opencl_missing()
pytestmark = pytest.mark.skipif(MISSING is not None, reason=str(MISSING))
ROOT = Path(rdsl.__file__).resolve().parent
GGX = ROOT / "bench" / "ggx_kernel.rdsl"
REF = "avx2" if host_supports(get_target("avx2")) else "scalar"


WIDTHS = (1, 8, 16)


@pytest.fixture(scope="module")
def cl_compiled():
    return {(f.stem, f"opencl{w}"): rdsl.jit(f, target="opencl", width=w)
            for w in WIDTHS for f in CORPUS.glob("*.rdsl")}


@pytest.mark.xdist_group("corpus-opencl")  # one worker: the module fixtures build once
@pytest.mark.parametrize("case", sorted(CASES), ids=lambda c: f"{c[0]}.{c[1]}")
def test_corpus_matches_interpreter(case, interp_modules, cl_compiled):  # noqa: F811
    check_case(case, interp_modules[case[0]], cl_compiled)


@pytest.mark.parametrize("path", STDLIB_BSDFS, ids=lambda p: p.stem)
def test_stdlib_bsdf_matches_llvm(path: Path):
    """Every kernel of the module, through the flat arguments of its manifest."""
    mod = rdsl.jit(path, target="opencl")
    ref = rdsl.jit(path, target=REF)
    assert mod.manifest["backend"] == "opencl" and mod.width == get_target("host").width
    rng = np.random.default_rng(5)
    n = 99 if path.stem in ("roughplastic", "common") else 999
    nonzero = 0
    for k in ref.manifest["kernels"]:
        inputs = _random_inputs(k, n, rng)
        want = _call_raw(ref._lib, k, inputs, n)
        got = [np.full(n, 7, w.dtype) for w in want]
        mod[k["name"]].launch(n, [inputs.get(a["name"]) for a in k["args"]], None, got)
        nonzero += assert_bitwise(k, got, want)
    assert nonzero > 0, "every output is 0 (a vacuous check)"


def _ggx_inputs(n: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    wi = rng.normal(size=(n, 3)).astype(np.float32)
    wi /= np.linalg.norm(wi, axis=1)[:, None]
    return wi, rng.random(n, dtype=np.float32), rng.random((n, 2), dtype=np.float32)


@pytest.mark.parametrize("width", WIDTHS)
def test_user_kernel_call_interface(width: int):
    """The GGX kernel called as on the CPU: fresh results, a scalar broadcast to every
    element, strided inputs, a mask (masked lanes keep ``out``'s values), and a second
    call over fewer elements reusing the device buffers."""
    cl_k = rdsl.jit(GGX, target="opencl", width=width)["ggx_eval_sample"]
    cpu_k = rdsl.jit(GGX, target=REF)["ggx_eval_sample"]
    wi, u1, u2 = _ggx_inputs(1001)
    want = cpu_k(wi, u1, u2, 0.3)
    got = cl_k(wi, u1, u2, 0.3)
    assert got.shape == (1001, 4) and np.count_nonzero(want) > 1000
    assert np.array_equal(_bits(got), _bits(want))
    alpha = np.linspace(0.01, 1, 1001, dtype=np.float32)
    wi_f = np.asfortranarray(wi)  # columns strided in memory
    assert np.array_equal(_bits(cl_k(wi_f, u1[::1], u2, alpha)),
                          _bits(cpu_k(wi, u1, u2, alpha)))
    mask = np.arange(1001) % 3 != 0
    out = np.full((1001, 4), -5.0, np.float32)
    assert cl_k(wi, u1, u2, 0.3, mask=mask, out=out) is out
    assert np.array_equal(out[mask], want[mask]) and np.all(out[~mask] == -5.0)
    small = cl_k(wi[:10], u1[:10], u2[:10], 0.3)
    assert np.array_equal(_bits(small), _bits(want[:10]))


def test_calls_from_threads_at_once():
    """A kernel called from several threads at once (as the renderer's thread pools do):
    each call gets its own results (calls share the device buffers, so they take turns)."""
    from concurrent.futures import ThreadPoolExecutor

    cl_k = rdsl.jit(GGX, target="opencl", width=8)["ggx_eval_sample"]
    cpu_k = rdsl.jit(GGX, target=REF)["ggx_eval_sample"]
    inputs = [_ggx_inputs(257 + 64 * k, seed=k) for k in range(8)]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(lambda x: cl_k(*x, 0.3), inputs * 3))
    for x, g in zip(inputs * 3, got):
        assert np.array_equal(_bits(g), _bits(cpu_k(*x, 0.3)))


def test_struct_results():
    """A stdlib plugin kernel with struct arguments and a struct result (diffuse.sample)."""
    cl_m = rdsl.jit(ROOT / "stdlib" / "bsdf" / "diffuse.rdsl", target="opencl")
    cpu_m = rdsl.jit(ROOT / "stdlib" / "bsdf" / "diffuse.rdsl", target=REF)
    n = 257
    wi, u1, u2 = _ggx_inputs(n, seed=2)
    z = np.zeros((n, 3), np.float32)
    si = {"p": z, "n": z, "sh_n": z, "uv": np.zeros((n, 2), np.float32), "wi": wi,
          "t": np.ones(n, np.float32), "valid": np.ones(n, bool)}
    got = cl_m["diffuse.sample"](si, u1, u2, reflectance=0.7)
    want = cpu_m["diffuse.sample"](si, u1, u2, reflectance=0.7)
    assert set(got) == set(want) == {"wo", "pdf", "eta", "weight", "delta"}
    for f in want:
        assert got[f].dtype == want[f].dtype and np.array_equal(_bits(got[f]), _bits(want[f]))
    assert np.any(got["pdf"] > 0)



def test_zero_elements():
    """A call over no elements returns empty results (it ran one element over empty
    arrays, and pyopencl failed to map a buffer of no bytes)."""
    k = rdsl.jit(GGX, target="opencl", width=8)["ggx_eval_sample"]
    wi, u1, u2 = _ggx_inputs(0, seed=3)
    want = rdsl.jit(GGX, target=REF)["ggx_eval_sample"](wi, u1, u2, 0.3)
    assert want.shape == (0, 4)
    for got in (k(wi, u1, u2, 0.3), k(wi, u1, u2, 0.3, mask=np.zeros(0, bool))):
        assert got.shape == (0, 4) and got.dtype == np.float32

def test_cli_writes_and_loads(tmp_path: Path):
    src = tmp_path / "shade.rdsl"
    src.write_text(HOST_SRC)
    r = rdsl_cli("compile", str(src), "--target", "opencl", "-o", str(tmp_path / "shade"))
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "shade.cl").read_text()
    assert "__kernel void rdsl_shade(" in text
    mod = rdsl.load(tmp_path / "shade.cl")
    assert mod.target == "opencl"
    a = np.linspace(-2, 2, 11, dtype=np.float32)
    got = mod["shade"](a, a[::-1].copy(), np.full(11, 3, np.int32), np.ones(11, bool))
    assert np.array_equal(got, a * a[::-1] + np.float32(3))
    assert_user_error(rdsl_cli("compile", str(src), "--target", "opencl", "--width", "3"),
                      "unsupported SIMD width 3 for target `opencl`")
    assert_user_error(rdsl_cli("compile", str(src), "--target", "opencl", "--emit", "asm"),
                      "needs an LLVM target")


def test_no_platform_is_one_clear_line(tmp_path: Path):
    """No OpenCL driver (an empty ICD folder): loading says what to install, no traceback."""
    src = tmp_path / "shade.rdsl"
    src.write_text(HOST_SRC)
    assert rdsl_cli("compile", str(src), "--target", "opencl", "-o",
                    str(tmp_path / "shade")).returncode == 0
    (tmp_path / "icd").mkdir()
    code = f"import rdsl; rdsl.load({str(tmp_path / 'shade.cl')!r})"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False,
                       env={"OCL_ICD_VENDORS": str(tmp_path / "icd"), "PATH": "/usr/bin",
                            "HOME": str(tmp_path)})
    assert r.returncode != 0
    assert "no OpenCL platform" in r.stderr and "pocl-opencl-icd" in r.stderr, r.stderr


def test_no_pyopencl(monkeypatch):
    from rdsl.runtime import opencl

    monkeypatch.setattr(opencl, "_CONTEXT", [])
    monkeypatch.setitem(sys.modules, "pyopencl", None)  # import fails
    with pytest.raises(opencl.OpenCLUnavailable, match=r"pip install pyopencl"):
        rdsl.jit(HOST_SRC, target="opencl")


# -- rendering: the film on the device; ray queries wait for the BVH in rdsl -------------

SKYDIR = """// traces no rays: the camera ray's direction, jittered by the sampler
import render.integrator;

integrator skydir {
    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum {
        let (s, u) = next_1d(sampler);
        return Spectrum(0.5 * (ray.d.y + 1.0) + 0.1 * u);
    }
}
"""


def _skydir_scene(tmp_path: Path) -> Path:
    from _scenes import CBOX

    xml = CBOX.read_text()
    start, end = xml.index("<integrator"), xml.index("</integrator>") + len("</integrator>")
    (tmp_path / "skydir.rdsl").write_text(SKYDIR)
    scene = tmp_path / "cbox.xml"
    scene.write_text(xml[:start] + '<integrator type="skydir"/>' + xml[end:])
    return scene


def test_render_without_rays_matches_llvm(tmp_path: Path):
    """A scene whose integrator traces no rays renders through the OpenCL kernels (scene
    buffers and the film on the device) to the LLVM target's image, bit for bit (the film
    sums each pixel's samples in one lane, in order)."""
    scene = _skydir_scene(tmp_path)
    imgs = {}
    for target in ("opencl", REF):
        s = rdsl.load_scene(scene, target=target, res=24, spp=3)
        imgs[target] = s.render()
        if target == "opencl":
            from rdsl.runtime.opencl import DeviceBuffer

            assert all(isinstance(b, DeviceBuffer) for b in s._scene_args(s.compile()))
            assert np.array_equal(s.render(), imgs[target])  # the device buffers, again
    assert imgs[REF].shape == (24, 24, 3) and np.ptp(imgs[REF]) > 0.1
    assert np.array_equal(imgs["opencl"], imgs[REF])


def test_render_tracing_rays_is_one_clear_line(tmp_path: Path):
    """Embree asked for on OpenCL (the default there is the rdsl BVH): one clear line."""
    from _scenes import CBOX

    r = rdsl_cli("render", str(CBOX), "-D", "res=8", "-D", "spp=1", "--target", "opencl",
                 "--accel", "embree", "-o", str(tmp_path / "x.exr"))
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0, r.stderr
    assert "the scene traces rays" in r.stderr and "BVH written in rdsl" in r.stderr


@pytest.mark.skipif(not (ROOT / "stdlib" / "render" / "bvh.rdsl").is_file(),
                    reason="needs the BVH written in rdsl (stdlib/render/bvh.rdsl)")
def test_cornell_box_with_rdsl_bvh():
    """The Cornell box traced by the rdsl BVH on OpenCL: the image of the same BVH on the
    LLVM target bit for bit (the same IR, and both targets round alike), and Embree's
    within float noise (a hit's t and barycentrics differ in the last bits)."""
    from _scenes import CBOX

    imgs = {}
    for target, accel in (("opencl", "bvh"), (REF, "bvh"), (REF, "embree")):
        s = rdsl.load_scene(CBOX, target=target, accel=accel, res=32, spp=4)
        imgs[target, accel] = s.render()
    assert np.array_equal(imgs["opencl", "bvh"], imgs[REF, "bvh"])
    assert np.abs(imgs["opencl", "bvh"] - imgs[REF, "embree"]).max() < 1e-3
    assert imgs[REF, "embree"].mean() > 0.05


@pytest.mark.skipif(not (ROOT / "stdlib" / "render" / "bvh.rdsl").is_file(),
                    reason="needs the BVH written in rdsl (stdlib/render/bvh.rdsl)")
def test_spectral_cornell_box_with_rdsl_bvh():
    """A spectral render on OpenCL: the LLVM target's image with the same BVH bit for bit,
    and unbiased against Mitsuba 3's spectral reference (the image means agree within the
    noise of 16 spp at 32x32: 3%; measured 0.1416 against 0.1443, where rgb gives 0.1500)."""
    from _scenes import CBOX

    from rdsl.runtime.render.image import read_exr

    imgs = {}
    for target in ("opencl", REF):
        s = rdsl.load_scene(CBOX, target=target, accel="bvh", variant="spectral", res=32,
                            spp=16)
        imgs[target] = s.render()
    assert np.array_equal(imgs["opencl"], imgs[REF])
    ref = read_exr(ROOT / "examples" / "cbox" / "cbox_ref_spectral.exr")[..., :3]
    np.testing.assert_allclose(imgs["opencl"].mean(), ref.mean(), rtol=0.03)


@pytest.mark.parametrize("width", (8, 16))
def test_gather_of_masked_lanes_reads_nothing(tmp_path: Path, width: int):
    """A gather at indices far outside the buffer in masked-off lanes (the printer's
    vector-literal gather loads element 0 there instead): active lanes equal the LLVM
    build's, masked lanes keep ``out``'s values, and nothing faults."""
    src = tmp_path / "pick.rdsl"
    src.write_text("fn pick(table: [Float], i: Int) -> Float {\n"
                   "    return table[i] * 2.0 + table[(i + 1) % 7];\n}\n")
    cl_k = rdsl.jit(src, target="opencl", width=width)["pick"]
    cpu_k = rdsl.jit(src, target=REF)["pick"]
    table = np.arange(7, dtype=np.float32) + 0.5
    n = 301
    idx = np.arange(n, dtype=np.int32) % 7
    mask = np.arange(n) % 3 != 0
    wild = np.where(mask, idx, np.int32(-2 ** 31 + 5)).astype(np.int32)
    out = np.full(n, -5.0, np.float32)
    cl_k(table, wild, mask=mask, out=out)
    want = cpu_k(table, idx)
    assert np.array_equal(out[mask], want[mask]) and np.all(out[~mask] == -5.0)
