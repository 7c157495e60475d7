"""The PTX backend (``--target ptx --arch sm_70|sm_80|sm_90``): every stdlib BSDF, emitter
and texture plugin assembles with NVIDIA's ``ptxas`` for each architecture; the PTX keeps
the IR's float semantics (no FMA contraction, IEEE division and square root, no flush to
zero); the Cornell box render kernel refuses Embree's ray queries with a diagnostic that
names them and ``--accel bvh``, and assembles once the BVH in rdsl traces its rays; the
command line writes ``.ptx`` plus a manifest; without a GPU ``rdsl render --target ptx``
says so in one line and exits 1.  Where a CUDA GPU is present, the kernels run on it and
agree with the CPU build bit for bit (skipped elsewhere, naming why).

``ptxas`` comes from the CUDA toolkit or the ``nvidia-cuda-nvcc-cu12`` wheel (CUDA 13's
no longer assembles for sm_70: the sm_70 PTX is then assembled for the oldest GPU it lists,
which checks it as PTX for ``.target sm_70``, not as sm_70 machine code)."""

from __future__ import annotations

import json
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.backends.ptx import (
    emit_ptx,
    find_ptxas,
    ptxas_archs,
    ptxas_candidates,
    run_ptxas,
)
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import compile_kernels
from rdsl.compiler.targets import PTX_ARCHS, ptx_target
from test_cli import assert_user_error
from test_cli import rdsl as rdsl_cli

ROOT = Path(rdsl.__file__).resolve().parent
STDLIB = ROOT / "stdlib"
PLUGINS = sorted(p for kind in ("bsdf", "emitter", "texture")
                 for p in (STDLIB / kind).glob("*.rdsl"))
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
BVH_LANDED = (STDLIB / "render" / "bvh.rdsl").is_file()


@cache
def _assembler(arch: str) -> tuple[Path, str] | None:
    """(ptxas, GPU name) to check PTX for ``arch``: a ptxas that lists ``arch``, else the
    oldest newer GPU some ptxas lists."""
    exe = find_ptxas(arch)
    if exe is not None:
        return exe, arch
    for p in ptxas_candidates():
        newer = sorted((a for a in ptxas_archs(p) if re.fullmatch(r"sm_\d+", a)
                        and int(a[3:]) > int(arch[3:])), key=lambda a: int(a[3:]))
        if newer:
            return p, newer[0]
    return None


def _ptxas(arch: str) -> tuple[Path, str]:
    found = _assembler(arch)
    if found is None:
        pytest.skip("ptxas not found (install the CUDA toolkit or `pip install "
                    "nvidia-cuda-nvcc-cu12`, or set RDSL_PTXAS)")
    return found


@cache
def _ir(path: Path):
    """The plugin's kernels as IR for the ptx target (the same for every architecture)."""
    module, _ = compile_kernels(path, Build.of(ptx_target(), "rgb"))
    return module


def _check_float_semantics(ptx: str) -> None:
    """The IR's arithmetic, bit for bit: explicit round-to-nearest on every f32 add, sub
    and mul (ptxas fuses those without it), IEEE division and sqrt, denormals kept."""
    assert not re.search(r"\b(add|sub|mul)\.f32\b", ptx), "an f32 op ptxas may contract"
    assert not re.search(r"\b(div|sqrt)\.(approx|full)", ptx), "an approximate div/sqrt"
    assert ".ftz" not in ptx, "flush to zero"
    assert ".extern" not in ptx, "an unresolved function"
    assert "fma." not in ptx, "a fused multiply-add (the IR has none)"


def _one_worker(items: list, name) -> list:
    """``items`` as params each of whose architectures run on one worker (``--dist
    loadgroup``), so that the IR they share (``@cache``) compiles once."""
    return [pytest.param(x, id=name(x), marks=pytest.mark.xdist_group(f"ptx-{name(x)}"))
            for x in items]


@pytest.mark.parametrize("arch", PTX_ARCHS)
@pytest.mark.parametrize("path", _one_worker(PLUGINS, lambda p: f"{p.parent.name}.{p.stem}"))
def test_stdlib_plugin_passes_ptxas(path: Path, arch: str):
    exe, gpu = _ptxas(arch)
    module = _ir(path)
    ptx = emit_ptx(module, ptx_target(arch))
    assert f".target {arch}" in ptx
    names = {k.name for k in module.functions.values() if k.attrs.get("export")}
    entries = set(re.findall(r"\.visible \.entry (\w+)\(", ptx))
    from rdsl.compiler.backends.base import c_name

    assert entries == {"rdsl_" + c_name(n) for n in names}
    _check_float_semantics(ptx)
    report = run_ptxas(ptx, gpu, exe)
    assert "error" not in report.lower()


# -- the render kernel --------------------------------------------------------------------


def _cbox(accel: str | None = None, path: Path = CBOX, variant: str = "rgb"):
    from rdsl.runtime.render.renderer import Scene

    kw = {} if accel is None else {"accel": accel}
    return Scene(path, Build.of(ptx_target(), variant), **kw)


def test_render_kernel_with_embree_queries_is_refused():
    module = _cbox(accel="embree").kernel_ir()
    with pytest.raises(CompileError) as e:
        emit_ptx(module, ptx_target("sm_80"))
    msg = str(e.value)
    assert "ray query `trace`" in msg and "--accel bvh" in msg
    assert "integrator.rdsl" in msg  # points at the stdlib line that traces


@pytest.mark.skipif(not BVH_LANDED, reason="the BVH in rdsl (stdlib/render/bvh.rdsl, "
                    "issue 14 item 1) has not landed: the render kernel's rays need it")
@pytest.mark.xdist_group("ptx-cbox")  # the IR they share (@cache) compiles once
@pytest.mark.parametrize("arch", PTX_ARCHS)
def test_cbox_render_kernel_passes_ptxas(arch: str):
    exe, gpu = _ptxas(arch)
    ptx = _cbox_bvh_ptx(arch)
    assert ".visible .entry rdsl_render_sample(" in ptx
    assert ".visible .entry rdsl_film_pass(" in ptx
    _check_float_semantics(ptx)
    run_ptxas(ptx, gpu, exe)


@cache
def _cbox_bvh_module():
    return _cbox("bvh").kernel_ir()


def _cbox_bvh_ptx(arch: str) -> str:
    return emit_ptx(_cbox_bvh_module(), ptx_target(arch))


# the stdlib integrators besides the Cornell box's path tracer, in its scene
INTEGRATORS = {
    "direct": ('<integrator type="direct"/>', "rgb"),
    "depth": ('<integrator type="depth"/>', "rgb"),
    "aov": (('<integrator type="aov"><string name="aovs" value="d:depth,n:sh_normal"/>'
             '<integrator type="path"/></integrator>'), "rgb"),
    "stokes": ('<integrator type="stokes"><integrator type="path"/></integrator>',
               "spectral_polarized"),
    "moment": ('<integrator type="moment"><integrator type="path"/></integrator>', "rgb"),
}


def test_every_stdlib_integrator_is_covered():
    assert {p.stem for p in (STDLIB / "integrator").glob("*.rdsl")} == {*INTEGRATORS, "path"}


@cache
def _integrator_module(name: str, folder: Path):
    xml, variant = INTEGRATORS[name]
    text = re.sub(r'<integrator type="path">.*?</integrator>', xml, CBOX.read_text(),
                  count=1, flags=re.DOTALL)
    path = folder / f"cbox_{name}.xml"
    path.write_text(text)
    return _cbox("bvh", path, variant).kernel_ir()


@pytest.mark.skipif(not BVH_LANDED, reason="the BVH in rdsl (stdlib/render/bvh.rdsl, "
                    "issue 14 item 1) has not landed: the render kernel's rays need it")
@pytest.mark.parametrize("arch", PTX_ARCHS)
@pytest.mark.parametrize("name", _one_worker(sorted(INTEGRATORS), str))
def test_stdlib_integrator_passes_ptxas(name: str, arch: str, tmp_path_factory):
    exe, gpu = _ptxas(arch)
    ptx = emit_ptx(_integrator_module(name, tmp_path_factory.getbasetemp()), ptx_target(arch))
    assert ".visible .entry rdsl_render_sample(" in ptx
    _check_float_semantics(ptx)
    run_ptxas(ptx, gpu, exe)


# -- the command line ---------------------------------------------------------------------


def test_compile_writes_ptx_and_manifest(tmp_path: Path):
    r = rdsl_cli("compile", str(STDLIB / "bsdf" / "diffuse.rdsl"), "--target", "ptx",
                 "--arch", "sm_80", "-o", str(tmp_path / "d"))
    assert r.returncode == 0, r.stderr
    ptx = (tmp_path / "d.ptx").read_text()
    man = json.loads((tmp_path / "d.json").read_text())
    assert ".target sm_80" in ptx and man["arch"] == "sm_80" and man["target"] == "ptx"
    assert man["width"] == 1 and man["backend"] == "ptx"
    for k in man["kernels"]:
        assert f".visible .entry {k['symbol']}(" in ptx
        # n, then each argument (and the stride of an array), then the mask and its stride
        params = 1 + sum(1 + a["strided"] for a in k["args"]) + 2
        decl = re.search(rf"\.entry {k['symbol']}\((.*?)\)", ptx, re.DOTALL).group(1)
        assert decl.count(".param") == params
    assert not (tmp_path / "d.so").exists()


@pytest.mark.parametrize("args, needle", [
    (["--target", "ptx", "--arch", "sm_75"], "unknown GPU architecture `sm_75`"),
    (["--target", "avx2", "--arch", "sm_80"], "--arch picks the GPU architecture"),
    (["--target", "ptx", "--emit", "obj"], "--emit obj needs a CPU target"),
    (["--target", "ptx", "--width", "8"], "target `ptx` has SIMD width 1, not 8"),
])
def test_compile_mistakes(tmp_path: Path, args: list[str], needle: str):
    r = rdsl_cli("compile", str(STDLIB / "bsdf" / "diffuse.rdsl"), *args, "-o",
                 str(tmp_path / "d"))
    assert_user_error(r, needle)


def test_trace_in_a_user_kernel_is_a_diagnostic_at_its_line(tmp_path: Path):
    src = tmp_path / "rays.rdsl"
    src.write_text("fn blocked(o: Vec3, d: Vec3) -> Bool {\n"
                   "    return occluded(Ray { o: o, d: d, tmax: 1.0 });\n}\n")
    r = rdsl_cli("compile", str(src), "--target", "ptx", "-o", str(tmp_path / "r"))
    assert_user_error(r, "rays.rdsl:2:", "ray query `occluded`", "--accel bvh")


# -- running: only with a GPU -------------------------------------------------------------


def _gpu_reason() -> str | None:
    from rdsl.runtime.cuda import cuda_status

    return cuda_status()


@pytest.mark.skipif(_gpu_reason() is None, reason="a CUDA GPU is present")
def test_render_without_gpu_says_so_in_one_line(tmp_path: Path):
    r = rdsl_cli("render", str(CBOX), "--target", "ptx", "-o", str(tmp_path / "x.exr"),
                 "--quiet")
    assert_user_error(r, "--target ptx needs a CUDA GPU")
    assert len(r.stderr.strip().splitlines()) == 1 and r.stdout == ""
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.skipif(_gpu_reason() is not None,
                    reason=f"no CUDA GPU to launch on: {_gpu_reason()}")
def test_gpu_kernels_match_the_cpu():  # pragma: no cover - needs a GPU
    path = STDLIB / "bsdf" / "roughconductor.rdsl"
    gpu = rdsl.jit(path, target="ptx")
    cpu = rdsl.jit(path, target="scalar")
    rng = np.random.default_rng(1)
    n = 1000
    wo = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
    si = {"p": np.zeros((n, 3), np.float32), "n": np.tile([0, 0, 1], (n, 1)).astype(np.float32),
          "sh_n": np.tile([0, 0, 1], (n, 1)).astype(np.float32),
          "uv": np.zeros((n, 2), np.float32), "wi": rng.uniform(-1, 1, (n, 3)).astype(np.float32),
          "t": np.ones(n, np.float32), "valid": np.ones(n, bool)}
    got, want = gpu["roughconductor.eval"](si, wo), cpu["roughconductor.eval"](si, wo)
    assert np.array_equal(got.view(np.uint32), want.view(np.uint32))


# -- the launcher's marshalling, without a GPU ---------------------------------------------


class _HostDriver:
    """The libcuda calls runtime/cuda.py makes, on host memory: "device" allocations are
    host buffers, and a launch calls the CPU build's entry point ``rdsl_<name>`` with the
    argument values the launcher packed (the PTX entry and the C entry take the same
    arguments, ``base.c_params``).  What this checks is the launcher's side only: which
    bytes it copies to and from the device, and how it packs the launch's arguments."""

    def __init__(self, cpu_lib) -> None:
        self.cpu_lib, self.mem, self.names, self.launches = cpu_lib, {}, {}, 0

    def cuInit(self, flags):
        return 0

    def cuDeviceGetCount(self, ref):
        ref._obj.value = 1
        return 0

    def cuDeviceGet(self, ref, ordinal):
        ref._obj.value = 0
        return 0

    def cuDevicePrimaryCtxRetain(self, ref, dev):
        return 0

    def cuCtxSetCurrent(self, ctx):
        return 0

    def cuModuleLoadData(self, ref, image):
        assert image.startswith(b"//") and image.endswith(b"\0")  # the PTX text, C string
        return 0

    def cuModuleGetFunction(self, ref, module, name):
        ref._obj.value = len(self.names) + 1
        self.names[ref._obj.value] = name.decode()
        return 0

    def cuMemAlloc_v2(self, ref, size):
        import ctypes

        buf = ctypes.create_string_buffer(b"\xa5" * size.value)  # not zeros: copies matter
        ref._obj.value = ctypes.addressof(buf)
        self.mem[ref._obj.value] = buf
        return 0

    def cuMemFree_v2(self, dev):
        del self.mem[dev.value]
        return 0

    def cuMemcpyHtoD_v2(self, dev, host, size):
        import ctypes

        ctypes.memmove(dev.value, host.value, size.value)
        return 0

    def cuMemcpyDtoH_v2(self, host, dev, size):
        import ctypes

        ctypes.memmove(host.value, dev.value, size.value)
        return 0

    def cuLaunchKernel(self, fn, gx, gy, gz, bx, by, bz, shared, stream, params, extra):
        import ctypes

        entry = getattr(self.cpu_lib, self.names[fn.value])
        values = []
        for k, t in enumerate(entry.argtypes):
            t = ctypes.c_uint64 if t is ctypes.c_void_p else t
            values.append(ctypes.cast(params[k], ctypes.POINTER(t)).contents.value)
        entry(*values)
        self.launches += 1
        return 0

    def cuCtxSynchronize(self):
        return 0


MARSHAL = """
fn splat(out: [Float], i: Int, p: Vec3, w: Float) -> Vec2 {
    out[i] = p.x * w + p.z;
    return Vec2(p.y * w, w);
}
"""


@pytest.mark.parametrize("source", ["roughconductor", "splat"])
def test_launcher_packs_and_copies_what_the_cpu_entry_reads(source: str, monkeypatch,
                                                            tmp_path: Path):
    from rdsl.compiler.backends.clib import manifest
    from rdsl.runtime import cuda

    src = STDLIB / "bsdf" / "roughconductor.rdsl" if source == "roughconductor" else MARSHAL
    cpu = rdsl.jit(src, target="scalar")
    module, _ = compile_kernels(src, Build.of(ptx_target(), "rgb"))
    fake = _HostDriver(cpu._lib)
    monkeypatch.setattr(cuda, "_driver", lambda: fake)
    gpu = cuda.CudaModule(manifest(module, ptx_target()), emit_ptx(module))
    rng = np.random.default_rng(5)
    n = 257
    mask = rng.random(n) < 0.7
    if source == "roughconductor":
        vec = lambda k: rng.uniform(-1, 1, (n, k)).astype(np.float32)
        si = {"p": vec(3), "n": vec(3), "sh_n": vec(3), "uv": vec(2), "wi": vec(3),
              "t": np.ones(n, np.float32), "valid": mask}
        wo = vec(3)[:, ::-1]  # a strided view: negative-free strides, not contiguous
        calls = [("roughconductor.eval", (si, wo), {"alpha": 0.3}),
                 ("roughconductor.pdf", (si, wo), {"mask": mask})]
    else:
        p = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        idx = rng.permutation(n).astype(np.int32)
        calls = [("splat", (np.zeros(n, np.float32), idx, p, np.float32(0.5)), {})]
    for name, args, kw in calls:
        want = cpu[name](*[a.copy() if isinstance(a, np.ndarray) else a for a in args], **kw)
        got_args = [a.copy() if isinstance(a, np.ndarray) else a for a in args]
        got = gpu[name](*got_args, **kw)
        assert np.array_equal(np.asarray(got).view(np.uint32), np.asarray(want).view(np.uint32))
        if source == "splat":  # the buffer written on the device came back
            ref = args[0].copy()
            cpu[name](ref, *args[1:])
            assert np.array_equal(got_args[0], ref) and np.count_nonzero(ref) > n // 2
    assert fake.launches == len(calls) and not fake.mem  # one launch per call, all freed


# -- float `rem`: exact on the GPU too -----------------------------------------------------


def _fmodf_on_cpu():
    """rdsl.fmodf (ptx_ops.define_fmodf), JIT-compiled for this CPU behind an array loop."""
    import ctypes

    import llvmlite.binding as llvm
    import llvmlite.ir as L
    from rdsl.compiler.backends.ptx_ops import define_fmodf

    mod = L.Module("fmodf")
    mod.triple = llvm.get_default_triple()
    f32, i64, ptr = L.FloatType(), L.IntType(64), L.PointerType()
    fm = define_fmodf(mod)
    fn = L.Function(mod, L.FunctionType(L.VoidType(), [ptr, ptr, ptr, i64]), "apply")
    x, y, out, n = fn.args
    pre = fn.append_basic_block("entry")
    loop, done = fn.append_basic_block("loop"), fn.append_basic_block("done")
    b = L.IRBuilder(pre)
    b.cbranch(b.icmp_signed(">", n, L.Constant(i64, 0)), loop, done)
    b.position_at_end(loop)
    i = b.phi(i64)
    i.add_incoming(L.Constant(i64, 0), pre)
    load = lambda p: b.load(b.gep(p, [i], source_etype=f32), typ=f32)
    b.store(b.call(fm, [load(x), load(y)]), b.gep(out, [i], source_etype=f32))
    nxt = b.add(i, L.Constant(i64, 1))
    i.add_incoming(nxt, loop)
    b.cbranch(b.icmp_signed("<", nxt, n), loop, done)
    b.position_at_end(done)
    b.ret_void()
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    ref = llvm.parse_assembly(str(mod))
    ref.verify()
    tm = llvm.Target.from_default_triple().create_target_machine()
    engine = llvm.create_mcjit_compiler(ref, tm)
    engine.finalize_object()
    cfn = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                           ctypes.c_int64)(engine.get_function_address("apply"))

    def run(a: np.ndarray, b_: np.ndarray) -> np.ndarray:
        out = np.empty_like(a)
        cfn(a.ctypes.data, b_.ctypes.data, out.ctypes.data, len(a))
        return out
    run.engine = engine  # keep the code alive
    return run


def test_ptx_float_rem_is_fmodf_bit_for_bit():
    """The function the ptx target calls for float `rem`, run on the CPU (the same LLVM IR;
    integer ops only), against numpy's fmod on random bit patterns of every magnitude,
    subnormals, zeros, infinities and NaNs."""
    rng = np.random.default_rng(7)
    n = 400_000
    x = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32).view(np.float32)
    y = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32).view(np.float32)
    with np.errstate(over="ignore", invalid="ignore"):  # y near x: few quotient bits
        near = (x * rng.uniform(0.1, 3.0, n).astype(np.float32)).astype(np.float32)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-45, -1e-45, 1.1754942e-38,
                        3.4028235e38, 1.0, -1.0, 0.1, 7.0], np.float32)
    sx, sy = (a.ravel() for a in np.meshgrid(special, special))
    xs = np.concatenate([x, x, sx, np.full(1000, 2.0**100, np.float32)])
    ys = np.concatenate([y, near, sy, np.full(1000, 3.0, np.float32)])
    got = _fmodf_on_cpu()(xs, ys)
    with np.errstate(invalid="ignore"):
        want = np.fmod(xs, ys)
    same = (got.view(np.uint32) == want.view(np.uint32)) | (np.isnan(got) & np.isnan(want))
    assert same.all(), (xs[~same][:5], ys[~same][:5], got[~same][:5], want[~same][:5])


def test_float_rem_in_ptx_calls_it_and_no_fma():
    module, _ = compile_kernels("fn m(a: Float, b: Float) -> Float { return a % b; }",
                                Build.of(ptx_target(), "rgb"))
    ptx = emit_ptx(module, ptx_target("sm_80"))
    assert "clz.b32" in ptx and "fma" not in ptx and "cvt.rzi" not in ptx
    _check_float_semantics(ptx)
