"""The Python runtime: argument conversion, structured params and results, errors, threads,
``rdsl.load`` and the ``rdsl.jit`` disk cache."""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _backend_util import add_kernel, build_and_load, new_module, vt
from rdsl.compiler import ir
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.targets import host_target

Op = ir.Op
VEC3 = {"kind": "vec", "n": 3, "dtype": "f32"}
F32J = {"kind": "scalar", "dtype": "f32"}
SURF = {"kind": "struct", "name": "Surf", "fields": [
    ["p", VEC3], ["t", F32J], ["valid", {"kind": "scalar", "dtype": "bool"}]]}
SAMPLE = {"kind": "struct", "name": "Sample", "fields": [["value", VEC3], ["pdf", F32J]]}


def _shading_module(width: int) -> ir.Module:
    """shade(si: Surf, wo: Vec3; alpha: Float = 0.5, color: Vec3 = (0.2, 0.3, 0.4)) -> Sample
    value = valid ? wo * color * alpha : 0;  pdf = si.t + si.p.x.   Also lerp(a, b, t)."""
    m = new_module(width, variant="rgb")
    W = width
    f = vt("f32", W)
    xyz = ("x", "y", "z")
    params = [(f"si.p.{c}", "f32", "varying") for c in xyz] + [
        ("si.t", "f32", "varying"), ("si.valid", "bool", "varying")] + [
        (f"wo.{c}", "f32", "varying") for c in xyz] + [("alpha", "f32", "uniform", 0.5)] + [
        (f"color.{c}", "f32", "uniform") for c in xyz]

    def shade(b, a, mask):
        zero = b.op(Op.BROADCAST, f, b.const(0.0, ir.F32))
        al = b.op(Op.BROADCAST, f, a["alpha"])
        out = []
        for c in xyz:
            v = b.op(Op.MUL, f, b.op(Op.MUL, f, a[f"wo.{c}"],
                                     b.op(Op.BROADCAST, f, a[f"color.{c}"])), al)
            out.append(b.op(Op.SELECT, f, a["si.valid"], v, zero))
        out.append(b.op(Op.ADD, f, a["si.t"], a["si.p.x"]))
        return out
    fn = add_kernel(m, "bsdf.shade", params, shade,
                    ["ret.value.x", "ret.value.y", "ret.value.z", "ret.pdf"])
    fn.attrs["abi_params"] = [
        {"name": "si", "type": SURF, "uniform": False, "default": None,
         "leaves": ["si.p.x", "si.p.y", "si.p.z", "si.t", "si.valid"]},
        {"name": "wo", "type": VEC3, "uniform": False, "default": None,
         "leaves": ["wo.x", "wo.y", "wo.z"]},
        {"name": "alpha", "type": F32J, "uniform": True, "default": 0.5, "leaves": ["alpha"]},
        {"name": "color", "type": VEC3, "uniform": True, "default": [0.2, 0.3, 0.4],
         "leaves": ["color.x", "color.y", "color.z"]}]
    fn.attrs["abi_result"] = {"type": SAMPLE, "leaves": fn.ret_names}

    def lerp(b, a, mask):
        d = b.op(Op.SUB, f, a["b"], a["a"])
        return [b.op(Op.ADD, f, a["a"], b.op(Op.MUL, f, a["t"], d))]
    add_kernel(m, "lerp", [("a", "f32", "varying"), ("b", "f32", "varying"),
                           ("t", "f32", "varying")], lerp)

    def count(b, a, mask):  # i32 param, tuple result, uniform result
        i = a["i"]
        return [b.op(Op.ADD, vt("i32", W), i, i), b.op(Op.ANY, ir.BOOL, mask)]
    add_kernel(m, "count", [("i", "i32", "varying")], count, ["ret.0", "ret.1"])
    return m


@pytest.fixture(scope="module")
def mod(tmp_path_factory):
    t = host_target()
    return build_and_load(_shading_module(t.width), t.name, tmp_path_factory.mktemp("rt"))


def _surf(n, rng):
    return {"p": rng.standard_normal((n, 3)).astype(np.float32),
            "t": rng.random(n).astype(np.float32), "valid": rng.random(n) < 0.7}


def test_struct_and_vec_params(mod):
    rng = np.random.default_rng(0)
    n = 101
    si, wo = _surf(n, rng), rng.standard_normal((n, 3)).astype(np.float32)
    res = mod["bsdf.shade"](si, wo, alpha=0.25, color=(1.0, 2.0, 3.0))
    assert set(res) == {"value", "pdf"}
    assert res["value"].shape == (n, 3) and res["pdf"].shape == (n,)
    col = np.array([1, 2, 3], dtype=np.float32)
    expected = np.where(si["valid"][:, None], wo * col * np.float32(0.25), 0)
    np.testing.assert_array_equal(res["value"], expected)
    np.testing.assert_array_equal(res["pdf"], si["t"] + si["p"][:, 0])
    # defaults from the manifest; a scalar where a vector uniform is expected
    d = mod.bsdf.shade(si, wo)
    col = np.array([0.2, 0.3, 0.4], dtype=np.float32)
    np.testing.assert_array_equal(d["value"], np.where(si["valid"][:, None],
                                                       wo * col * np.float32(0.5), 0))
    s = mod.bsdf.shade(si, wo, color=2.0, alpha=1)
    np.testing.assert_array_equal(s["value"], np.where(si["valid"][:, None], wo * 2, 0))


def test_scalars_broadcast_and_keywords(mod):
    a = np.arange(10, dtype=np.float64)  # converted to float32
    got = mod.lerp(a, 10.0, 0.5)
    np.testing.assert_array_equal(got, (a.astype(np.float32) + 10) * np.float32(0.5))
    np.testing.assert_array_equal(mod.lerp(a=a, b=a, t=[0.0] * 10), a.astype(np.float32))
    assert mod.lerp(1.0, 3.0, 0.5).tolist() == [2.0]


def test_tuple_and_uniform_results(mod):
    i = np.arange(20, dtype=np.int32)
    twice, any_ = mod.count(i)
    np.testing.assert_array_equal(twice, 2 * i)
    assert any_.dtype == np.bool_ and any_.all()
    mask = np.zeros(20, dtype=bool)
    mask[3] = True
    twice, _ = mod.count(i, mask=mask)
    assert twice[3] == 6 and (twice[~mask] == 0).all()


def test_value_errors(mod):
    t = np.zeros((5, 2), dtype=np.float32)
    with pytest.raises(ValueError, match=r"lerp\(\): parameter `t` expects a float32 array of "
                                         r"shape \(N,\), got shape \(5, 2\)"):
        mod.lerp(np.zeros(5), np.zeros(5), t)
    with pytest.raises(ValueError, match=r"count\(\): parameter `i` expects a int32 array .*"
                                         "got dtype float64"):
        mod.count(np.zeros(4))
    with pytest.raises(ValueError, match=r"lerp\(\): parameter `b` expects .*complex"):
        mod.lerp(np.zeros(3), np.zeros(3, dtype=complex), np.zeros(3))
    with pytest.raises(ValueError, match=r"lerp\(\): parameter `a` .*object"):
        mod.lerp(np.array([object()] * 3), np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match=r"lerp\(\): expected 3 positional arguments"):
        mod.lerp(1, 2, 3, 4)
    with pytest.raises(ValueError, match=r"lerp\(\): missing argument for parameter `t`"):
        mod.lerp(1, 2)
    with pytest.raises(ValueError, match=r"lerp\(\): parameter `b` has 4 elements, "
                                         r"expected 3 \(the length of `a`\)"):
        mod.lerp(np.zeros(3), np.zeros(4), 0.5)
    with pytest.raises(ValueError, match=r"lerp\(\): unexpected keyword argument `alpha`"):
        mod.lerp(1, 2, 3, alpha=2)
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match=r"bsdf.shade\(\): parameter `wo` expects a float32 "
                                         r"array of shape \(N, 3\), got shape \(4, 2\)"):
        mod["bsdf.shade"](_surf(4, rng), np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"parameter `si` is missing field `valid`"):
        mod["bsdf.shade"]({"p": np.zeros((4, 3)), "t": np.zeros(4)}, np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"parameter `color` expects 3 values, got 2"):
        mod["bsdf.shade"](_surf(4, rng), np.zeros((4, 3)), color=(1, 2))
    with pytest.raises(ValueError, match=r"uniform parameter `alpha` got None \(leave it out "
                                         r"for its default, 0.5\)"):
        mod["bsdf.shade"](_surf(4, rng), np.zeros((4, 3)), alpha=None)
    with pytest.raises(ValueError, match=r"`mask` has 2 elements, expected 4"):
        mod.count(np.zeros(4, dtype=np.int32), mask=[True, False])



def test_integers_out_of_range():
    """An integer an Int or UInt leaf cannot hold (an int64 array's, a uint32 over 2^31, a
    negative one for a UInt, a Python int) is an error naming the parameter, where numpy's
    conversion would wrap it around; integers that fit are converted."""
    m = rdsl.jit("fn mix(a: Int, b: UInt, c: UInt64) -> Int { return a + Int(b) + Int(c); }")
    one = np.ones(3, np.int32)
    want = np.array([3, 4, 5], np.int32)
    np.testing.assert_array_equal(m.mix(np.array([1, 2, 3], np.int64), one, 1), want)
    np.testing.assert_array_equal(m.mix(np.uint64([1, 2, 3]), np.int64(1), np.int8(1)), want)
    np.testing.assert_array_equal(m.mix(np.array(1), [1, 2, 3], 1), want)
    cases = [((np.array([1, 2 ** 40, 3]), one, one), r"`a` expects int32 values "
              r"\(-2147483648..2147483647\), got 1099511627776 in a int64 array"),
             ((np.array([2 ** 31], np.uint32), 1, 1), r"`a` expects int32 .* got 2147483648"),
             ((one, np.array([5, -1, 0]), one), r"`b` expects uint32 values \(0..4294967295\), "
              r"got -1 in a int64 array"),
             ((one, one, np.array([0, -3, 0], np.int16)), r"`c` expects uint64 values .* got -3"),
             ((2 ** 31, one, one), r"`a` expects int32 values .*, got 2147483648$"),
             ((one, -1, one), r"`b` expects uint32 values .*, got -1$"),
             ((one, one, np.array(2 ** 64, dtype=object)), r"`c` expects a uint64 array")]
    for args, message in cases:
        with pytest.raises(ValueError, match=r"mix\(\): parameter " + message):
            m.mix(*args)

def test_threads_give_identical_results(mod):
    rng = np.random.default_rng(2)
    n = 100_003
    si, wo = _surf(n, rng), rng.standard_normal((n, 3)).astype(np.float32)
    mask = rng.random(n) < 0.9
    one = mod["bsdf.shade"](si, wo, mask=mask, threads=1)
    many = mod["bsdf.shade"](si, wo, mask=mask, threads=4)
    for k in one:
        np.testing.assert_array_equal(one[k], many[k])
    np.testing.assert_array_equal(mod.lerp(wo[:, 0], wo[:, 1], wo[:, 2], threads=3),
                                  mod.lerp(wo[:, 0], wo[:, 1], wo[:, 2], threads=1))



def test_threads_argument(mod):
    """``threads=`` is a number of threads, 1 or more: 0, -1, 2.5 or "2" are an error, and a
    huge count runs on a few threads per core (it started a thread per few vectors)."""
    import os
    import threading

    from rdsl.runtime import kernel

    x = np.linspace(-1, 1, 100_003, dtype=np.float32)
    for bad in (0, -1, 2.5, "2", True):
        with pytest.raises(ValueError, match=r"lerp\(\): `threads` expects a number of "
                                             r"threads, 1 or more \(or None: every core\), "
                                             f"got {bad!r}"):
            mod.lerp(x, x, x, threads=bad)
    before = threading.active_count()
    cap = kernel.MAX_THREADS_PER_CORE * (os.cpu_count() or 1)
    np.testing.assert_array_equal(mod.lerp(x, 2 * x, 0.5, threads=10 ** 6),
                                  mod.lerp(x, 2 * x, 0.5, threads=1))
    assert threading.active_count() <= before + cap
    assert 10 ** 6 not in kernel._POOLS

def test_out_reuses_a_result(mod):
    rng = np.random.default_rng(3)
    n = 37
    first = mod["bsdf.shade"](_surf(n, rng), rng.standard_normal((n, 3)).astype(np.float32))
    si, wo = _surf(n, rng), rng.standard_normal((n, 3)).astype(np.float32)
    again = mod["bsdf.shade"](si, wo, out=first)
    assert again is first
    fresh = mod["bsdf.shade"](si, wo)
    for k in fresh:
        np.testing.assert_array_equal(again[k], fresh[k])
    i = np.arange(n, dtype=np.int32)
    res = mod.count(i)
    assert mod.count(3 * i, out=res) is res
    np.testing.assert_array_equal(res[0], 6 * i)
    with pytest.raises(ValueError, match=r"`out` is not a result of this kernel over 5 "):
        mod["bsdf.shade"](_surf(5, rng), np.zeros((5, 3)), out=first)



def test_zero_elements(mod):
    """A call over no elements returns empty results of the right shapes (vectors (0, k)),
    masked or into an empty ``out=``, rather than failing while it builds them."""
    rng = np.random.default_rng(5)
    si, wo = _surf(0, rng), np.zeros((0, 3), np.float32)
    for res in (mod["bsdf.shade"](si, wo), mod["bsdf.shade"](si, wo, mask=np.zeros(0, bool))):
        assert res["value"].shape == (0, 3) and res["value"].dtype == np.float32
        assert res["pdf"].shape == (0,)
    out = {"value": np.zeros((0, 3), np.float32), "pdf": np.zeros(0, np.float32)}
    assert mod["bsdf.shade"](si, wo, out=out) is out
    twice, any_ = mod.count(np.zeros(0, np.int32))
    assert twice.shape == (0,) and any_.shape == (0,)

def test_fresh_results_reuse_only_released_blocks(mod):
    """Large fresh results come from the kernel's output pool: a block is written again only
    once no result or view of it is alive, and a masked call still gets zeros outside the
    mask from a reused block."""
    n = 300_000  # over the pool's 1 MiB floor
    x = np.arange(n, dtype=np.float32)
    half = np.full(n, 0.5, np.float32)
    first = mod.lerp(x, x + 2, half)
    view = mod.lerp(x, x, half)[::3]  # only a view of the second result survives
    third = mod.lerp(x, x + 4, half)
    assert not any(np.shares_memory(a, b)
                   for a, b in ((first, view), (first, third), (view, third)))
    np.testing.assert_array_equal(first, x + 1)
    np.testing.assert_array_equal(view, x[::3])
    released = view.__array_interface__["data"][0]
    del view
    fourth = mod.lerp(x, x + 6, half)  # the second result's block, released
    assert fourth.__array_interface__["data"][0] == released
    np.testing.assert_array_equal(first, x + 1)
    np.testing.assert_array_equal(third, x + 2)
    np.testing.assert_array_equal(fourth, x + 3)
    del fourth
    on = np.arange(n) % 3 == 0
    masked = mod.lerp(x, x + 6, half, mask=on)
    assert masked.__array_interface__["data"][0] == released
    np.testing.assert_array_equal(masked, np.where(on, x + 3, 0))


def test_calls_queued_together(mod):
    rng = np.random.default_rng(4)
    n = 50_001
    si, wo = _surf(n, rng), rng.standard_normal((n, 3)).astype(np.float32)
    first = mod["bsdf.shade"](si, wo, threads=3, wait=False)
    second = mod.lerp(wo[:, 0], wo[:, 1], wo[:, 2], threads=3, wait=False)
    np.testing.assert_array_equal(second.result(), mod.lerp(wo[:, 0], wo[:, 1], wo[:, 2]))
    got, want = first.result(), mod["bsdf.shade"](si, wo)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k])


def test_load_paths_and_module(mod, tmp_path):
    path = mod.path
    for p in (path, path.with_suffix(".json"), path.with_suffix("")):
        m = rdsl.load(str(p))
        assert set(m.kernels) == {"bsdf.shade", "lerp", "count"}
    assert m.width == host_target().width and m.variant == "rgb" and not m.from_cache
    assert "lerp(a, b, t" in m.lerp.signature
    with pytest.raises(AttributeError, match="no kernel `nope`"):
        m.nope
    with pytest.raises(KeyError):
        m["nope"]
    with pytest.raises(FileNotFoundError, match="no compiled rdsl module"):
        rdsl.load(tmp_path / "missing.so")
    manifest = json.loads(path.with_suffix(".json").read_text())
    k = next(k for k in manifest["kernels"] if k["name"] == "bsdf.shade")
    assert k["symbol"] == "rdsl_bsdf_shade" and k["range_symbol"] == "rdsl_bsdf_shade_range"
    assert manifest["rdsl_version"] == rdsl.__version__
    assert [a["kind"] for a in k["args"]].count("output") == 4
    assert k["params"][0]["leaf_dtypes"] == ["f32", "f32", "f32", "f32", "bool"]


def test_rebuilt_library_is_reloaded(tmp_path):
    from rdsl.compiler.backends.clib import build_library

    t = host_target()

    def module(c: float) -> ir.Module:
        m = new_module(t.width)
        add_kernel(m, "k", [("x", "f32", "varying")], lambda b, a, mask: [
            b.op(Op.ADD, vt("f32", t.width), a["x"],
                 b.op(Op.BROADCAST, vt("f32", t.width), b.const(c, ir.F32)))])
        return m
    build_library(module(1.0), t, tmp_path, "lib")
    assert rdsl.load(tmp_path / "lib.so").k([0.0]).tolist() == [1.0]
    build_library(module(2.0), t, tmp_path, "lib")
    assert rdsl.load(tmp_path / "lib.so").k([0.0]).tolist() == [2.0]


# --------------------------------------------------------------------------------------
# rdsl.jit and the cache, with a stand-in for the driver


@pytest.fixture
def fake_driver(monkeypatch, tmp_path):
    calls = []
    src = tmp_path / "src"
    src.mkdir()
    main, lib = src / "main.rdsl", src / "lib.rdsl"
    main.write_text("import lib;\nfn lerp(a: Float, b: Float, t: Float) -> Float { ... }\n")
    lib.write_text("// helpers\n")

    def source_files(source_or_path):
        return [Path(source_or_path), lib] if Path(str(source_or_path)).exists() else [lib]

    def compile_kernels(source_or_path, build, **options):
        calls.append((str(source_or_path), build.target.name, build.model.name, options))
        return _shading_module(build.width), source_files(source_or_path)

    drv = types.ModuleType("rdsl.compiler.driver")
    drv.source_files, drv.compile_kernels = source_files, compile_kernels
    monkeypatch.setitem(sys.modules, "rdsl.compiler.driver", drv)
    import rdsl.compiler

    monkeypatch.setattr(rdsl.compiler, "driver", drv, raising=False)
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    return types.SimpleNamespace(calls=calls, main=main, lib=lib, cache=tmp_path / "cache")


def test_jit_cache_hit(fake_driver):
    m1 = rdsl.jit(fake_driver.main, target="host")
    assert not m1.from_cache and len(fake_driver.calls) == 1
    assert m1.compile_seconds > 0
    m2 = rdsl.jit(str(fake_driver.main), target="host")
    assert m2.from_cache and len(fake_driver.calls) == 1
    np.testing.assert_array_equal(m2.lerp([0.0, 1.0], 2.0, 0.5), [1.0, 1.5])
    entries = [p for p in fake_driver.cache.iterdir() if not p.name.startswith(".")]
    assert len(entries) == 1 and (entries[0] / "kernels.h").is_file()
    # a changed import, another variant or another target recompiles
    fake_driver.lib.write_text("// helpers, edited\n")
    assert not rdsl.jit(fake_driver.main).from_cache
    assert not rdsl.jit(fake_driver.main, variant="mono").from_cache
    assert not rdsl.jit(fake_driver.main, target="scalar").from_cache
    assert len(fake_driver.calls) == 4
    assert fake_driver.calls[-1][1:3] == ("scalar", "rgb")
    assert rdsl.jit(fake_driver.main, target="scalar").from_cache
    # cache=False compiles again and leaves the cache alone
    assert not rdsl.jit(fake_driver.main, cache=False).from_cache
    assert len(fake_driver.calls) == 5


def test_jit_source_text(fake_driver):
    text = "fn lerp(a: Float, b: Float, t: Float) -> Float { return a; }\n"
    assert not rdsl.jit(text).from_cache
    assert rdsl.jit(text).from_cache
    assert not rdsl.jit(text + "\n").from_cache


def test_jit_exports_builds_only_the_named_kernels(tmp_path, monkeypatch):
    """``exports=`` compiles the named kernels alone, with the results of the whole file's
    build; a name the file does not export is a diagnostic listing the ones it does."""
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path))
    src = ("fn double(x: Float) -> Float { return 2.0 * x; }\n"
           "fn square(x: Float) -> Float { return x * x; }\n")
    whole = rdsl.jit(src)
    only = rdsl.jit(src, exports=["square"])
    assert sorted(only.kernels) == ["square"] and sorted(whole.kernels) == ["double", "square"]
    x = np.linspace(-2, 2, 37, dtype=np.float32)
    np.testing.assert_array_equal(only["square"](x), whole["square"](x))
    with pytest.raises(CompileError, match="no exported function 'cube'.*double, square"):
        rdsl.jit(src, exports=["cube"])


def test_a_pending_call_holds_its_buffers():
    """A buffer passed to a call that has not finished is the caller's to drop: the pending
    call keeps it alive until ``result()`` (a render's BATCH row is a temporary)."""
    import gc
    import weakref

    m = rdsl.jit("fn scaled(i: Int, B: [Float]) -> Float { return B[0] * Float(i); }")
    buf = np.array([2.5], np.float32)
    held = weakref.ref(buf)
    pending = m.scaled(np.arange(100_000, dtype=np.int32), buf, threads=2, wait=False)
    del buf
    gc.collect()
    assert held() is not None
    np.testing.assert_array_equal(pending.result(), 2.5 * np.arange(100_000, dtype=np.float32))
    del pending
    gc.collect()
    assert held() is None


def test_a_call_over_given_ranges():
    """``ranges=`` runs exactly those element ranges, each as one task (backward's parts own
    gradient rows): each range's results as a call over the whole array gives them, the
    elements outside every range untouched in ``out``; a range past the call's elements is
    a clear error naming it."""
    m = rdsl.jit("fn scaled(i: Int, B: [Float]) -> Float { return B[0] * Float(i); }")
    i = np.arange(10_000, dtype=np.int32)
    buf = np.array([1.5], np.float32)
    whole = m.scaled(i, buf)
    ranges = [(0, 4096), (4096, 4099), (5000, 10_000)]
    for threads in (1, 2):
        out = np.full(i.size, -1.0, np.float32)
        m.scaled(i, buf, out=out, threads=threads, ranges=ranges)
        inside = np.zeros(i.size, bool)
        for lo, hi in ranges:
            inside[lo:hi] = True
        np.testing.assert_array_equal(out[inside], whole[inside])
        assert (out[~inside] == -1.0).all()
    with pytest.raises(ValueError, match=r"`ranges` has \(9000, 10001\), outside the call's "
                                         r"10000 elements"):
        m.scaled(i, buf, ranges=[(0, 10), (9000, 10_001)])
