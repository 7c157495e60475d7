"""The LLVM CPU backend against numpy implementations of docs/ir.md, bit for bit.

Every kernel is hand-built post-vectorize IR; each target the host can run compiles one
library holding all of them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _backend_util import add_kernel, build_and_load, new_module, runnable_targets, vt
from rdsl.compiler import ir
from rdsl.compiler.backends import llvm as llvm_backend
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.targets import TARGETS, get_target, host_supports, host_target

Op = ir.Op
NP = {"f32": np.float32, "i32": np.int32, "u32": np.uint32, "u64": np.uint64, "bool": np.bool_}
I32_MIN, I32_MAX = -(2**31), 2**31 - 1

# --------------------------------------------------------------------------------------
# Reference semantics (docs/ir.md) in numpy


def _wrap(x: np.ndarray, dtype: str) -> np.ndarray:
    """Python-int/int64 values wrapped into ``dtype`` (two's complement)."""
    bits = 64 if dtype == "u64" else 32
    u = np.array([int(v) & ((1 << bits) - 1) for v in x], dtype=np.uint64)
    return u.astype(np.uint32).view(np.int32) if dtype == "i32" else u.astype(NP[dtype])


def ref_div(a, b, dtype, rem=False):
    out = []
    for x, y in zip(a.tolist(), b.tolist()):
        if y == 0:
            out.append(0)
            continue
        q = abs(x) // abs(y) * (1 if (x < 0) == (y < 0) else -1)
        out.append(x - q * y if rem else q)
    return _wrap(out, dtype)


def ref_shift(a, s, dtype, left):
    bits = 64 if dtype == "u64" else 32
    out = []
    for x, y in zip(a.tolist(), s.tolist()):
        y &= bits - 1
        if left:
            out.append(x << y)
        else:
            out.append(x >> y)  # python >> is arithmetic on negative (i32) values
    return _wrap(out, dtype)


def ref_fptoint(a, dtype):
    lo, hi = {"i32": (I32_MIN, I32_MAX), "u32": (0, 2**32 - 1), "u64": (0, 2**64 - 1)}[dtype]
    out = []
    for x in a.tolist():
        if np.isnan(x):
            out.append(0)
        elif np.isinf(x):
            out.append(hi if x > 0 else lo)
        else:
            out.append(min(max(int(x), lo), hi))  # int() truncates toward zero
    return _wrap(out, dtype)


def bits(x: np.ndarray) -> np.ndarray:
    if x.dtype == np.float32:
        return x.view(np.uint32)
    return x


# (kernel name, op, operand dtypes, result dtype, reference)
SPECS: list[tuple[str, Op, tuple[str, ...], str, object]] = []


def spec(name, op, ins, out, ref):
    SPECS.append((name, op, ins, out, ref))


for _op, _f in ((Op.ADD, np.add), (Op.SUB, np.subtract), (Op.MUL, np.multiply),
                (Op.DIV, np.divide), (Op.REM, np.fmod)):
    spec(f"f32.{_op.value}", _op, ("f32", "f32"), "f32", _f)
for _dt in ("i32", "u32", "u64"):
    spec(f"{_dt}.add", Op.ADD, (_dt, _dt), _dt, lambda a, b: a + b)
    spec(f"{_dt}.sub", Op.SUB, (_dt, _dt), _dt, lambda a, b: a - b)
    spec(f"{_dt}.mul", Op.MUL, (_dt, _dt), _dt, lambda a, b: a * b)
    spec(f"{_dt}.div", Op.DIV, (_dt, _dt), _dt, lambda a, b, d=_dt: ref_div(a, b, d))
    spec(f"{_dt}.rem", Op.REM, (_dt, _dt), _dt, lambda a, b, d=_dt: ref_div(a, b, d, True))
    spec(f"{_dt}.shl", Op.SHL, (_dt, _dt), _dt,
         lambda a, b, d=_dt: ref_shift(a, b, d, True))
    spec(f"{_dt}.shr", Op.SHR, (_dt, _dt), _dt,
         lambda a, b, d=_dt: ref_shift(a, b, d, False))
    spec(f"{_dt}.and", Op.AND, (_dt, _dt), _dt, np.bitwise_and)
    spec(f"{_dt}.or", Op.OR, (_dt, _dt), _dt, np.bitwise_or)
    spec(f"{_dt}.xor", Op.XOR, (_dt, _dt), _dt, np.bitwise_xor)
    spec(f"{_dt}.not", Op.NOT, (_dt,), _dt, np.invert)
    spec(f"{_dt}.neg", Op.NEG, (_dt,), _dt, lambda a: (0 - a.astype(np.uint64)).astype(a.dtype)
         if a.dtype != np.int32 else (0 - a.astype(np.int64)).astype(np.int32))
    spec(f"{_dt}.min", Op.MIN, (_dt, _dt), _dt, lambda a, b: np.where(a < b, a, b))
    spec(f"{_dt}.max", Op.MAX, (_dt, _dt), _dt, lambda a, b: np.where(a > b, a, b))
    spec(f"{_dt}.abs", Op.ABS, (_dt,), _dt, lambda a: np.abs(a) if a.dtype == np.int32 else a)
    spec(f"f32.cast.{_dt}", Op.CAST, ("f32",), _dt, lambda a, d=_dt: ref_fptoint(a, d))
    spec(f"{_dt}.cast.f32", Op.CAST, (_dt,), "f32", lambda a: a.astype(np.float32))
    spec(f"{_dt}.cast.bool", Op.CAST, (_dt,), "bool", lambda a: a != 0)
    spec(f"bool.cast.{_dt}", Op.CAST, ("bool",), _dt, lambda a, d=_dt: a.astype(NP[d]))
    for _c in (Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE):
        spec(f"{_dt}.{_c.value}", _c, (_dt, _dt), "bool",
             getattr(np, {"eq": "equal", "ne": "not_equal", "lt": "less",
                          "le": "less_equal", "gt": "greater", "ge": "greater_equal"}[_c.value]))
for _c, _f in ((Op.EQ, np.equal), (Op.NE, np.not_equal), (Op.LT, np.less),
               (Op.LE, np.less_equal), (Op.GT, np.greater), (Op.GE, np.greater_equal)):
    spec(f"f32.{_c.value}", _c, ("f32", "f32"), "bool", _f)
spec("f32.neg", Op.NEG, ("f32",), "f32", lambda a: (a.view(np.uint32) ^ np.uint32(1 << 31))
     .view(np.float32))
spec("f32.abs", Op.ABS, ("f32",), "f32", lambda a: (a.view(np.uint32) & np.uint32(I32_MAX))
     .view(np.float32))
spec("f32.min", Op.MIN, ("f32", "f32"), "f32", lambda a, b: np.where(a < b, a, b))
spec("f32.max", Op.MAX, ("f32", "f32"), "f32", lambda a, b: np.where(a > b, a, b))
spec("f32.sqrt", Op.SQRT, ("f32",), "f32", np.sqrt)
spec("f32.floor", Op.FLOOR, ("f32",), "f32", np.floor)
spec("f32.ceil", Op.CEIL, ("f32",), "f32", np.ceil)
spec("f32.cast.bool", Op.CAST, ("f32",), "bool", lambda a: a != 0)
spec("bool.cast.f32", Op.CAST, ("bool",), "f32", lambda a: a.astype(np.float32))
spec("i32.cast.u64", Op.CAST, ("i32",), "u64", lambda a: a.astype(np.int64).astype(np.uint64))
spec("u32.cast.u64", Op.CAST, ("u32",), "u64", lambda a: a.astype(np.uint64))
spec("u64.cast.i32", Op.CAST, ("u64",), "i32", lambda a: a.astype(np.uint32).view(np.int32))
spec("u64.cast.u32", Op.CAST, ("u64",), "u32", lambda a: a.astype(np.uint32))
spec("i32.cast.u32", Op.CAST, ("i32",), "u32", lambda a: a.view(np.uint32))
spec("u32.cast.i32", Op.CAST, ("u32",), "i32", lambda a: a.view(np.int32))
spec("f32.bitcast.u32", Op.BITCAST, ("f32",), "u32", lambda a: a.view(np.uint32))
spec("i32.bitcast.f32", Op.BITCAST, ("i32",), "f32", lambda a: a.view(np.float32))
for _name, _op, _f in (("and", Op.AND, np.logical_and), ("or", Op.OR, np.logical_or),
                       ("xor", Op.XOR, np.logical_xor), ("eq", Op.EQ, np.equal),
                       ("ne", Op.NE, np.not_equal)):
    spec(f"bool.{_name}", _op, ("bool", "bool"), "bool", _f)
spec("bool.not", Op.NOT, ("bool",), "bool", np.logical_not)
spec("f32.select", Op.SELECT, ("bool", "f32", "f32"), "f32", lambda c, a, b: np.where(c, a, b))
spec("u64.select", Op.SELECT, ("bool", "u64", "u64"), "u64", lambda c, a, b: np.where(c, a, b))

N = 203  # not a multiple of any width: every run has a tail


def inputs(dtype: str, seed: int, n: int = N) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if dtype == "f32":
        special = np.array([0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1.5, -2.5, np.inf, -np.inf,
                            np.nan, 1e-40, -1e-42, 3.4e38, -3.4e38, 2.0**31, -(2.0**31),
                            2.0**32, 2.0**63, 2.0**64, 1e30, 16777217.0, 0.49999997],
                           dtype=np.float32)
        x = (rng.standard_normal(n) * 10.0 ** rng.integers(-3, 12, n)).astype(np.float32)
        x[: len(special)] = special
        return rng.permutation(x) if seed % 2 else x
    if dtype == "bool":
        return rng.integers(0, 2, n).astype(bool)
    info = np.iinfo(NP[dtype])
    special = [0, 1, 2, 3, -1, 31, 32, 33, 63, 64, 65, info.min, info.max, info.min + 1, -7, 7]
    x = rng.integers(info.min, info.max, n, dtype=NP[dtype], endpoint=True)
    small = rng.integers(-40, 70, n).astype(np.int64)
    x[n // 2:] = _wrap(small[n // 2:], dtype)  # many small values: shift amounts, divisors
    x[: len(special)] = _wrap(np.array(special, dtype=object), dtype)
    return rng.permutation(x) if seed % 2 else x


def _op_module(width: int) -> ir.Module:
    m = new_module(width)
    for name, op, ins, out, _ in SPECS:
        params = [(f"a{i}", dt, "varying") for i, dt in enumerate(ins)]

        def body(b, args, mask, op=op, ins=ins, out=out):
            vals = [args[f"a{i}"] for i in range(len(ins))]
            return [b.op(op, vt(out, width), *vals)]
        add_kernel(m, name, params, body)
    return m


# one worker per target (under --dist loadgroup): the library builds once
@pytest.fixture(scope="module", params=[
    pytest.param(*t.values, id=t.values[0],
                 marks=[*t.marks, pytest.mark.xdist_group(f"ops-{t.values[0]}")])
    for t in runnable_targets()])
def ops_lib(request, tmp_path_factory):
    t = get_target(request.param)
    return build_and_load(_op_module(t.width), t.name, tmp_path_factory.mktemp(t.name))


@pytest.mark.parametrize("name", [s[0] for s in SPECS])
def test_op_semantics(ops_lib, name):
    _, op, ins, out, ref = next(s for s in SPECS if s[0] == name)
    args = [inputs(dt, seed=i + 1) for i, dt in enumerate(ins)]
    with np.errstate(all="ignore"):
        expected = np.asarray(ref(*args)).astype(NP[out])
    got = ops_lib[name](*args)
    assert got.dtype == NP[out]
    np.testing.assert_array_equal(bits(got), bits(expected), err_msg=f"{name} on {args}")


# --------------------------------------------------------------------------------------
# Control flow, memory and vector ops


def _features_module(width: int) -> ir.Module:
    m = new_module(width)
    W = width
    f, i32, bl = vt("f32", W), vt("i32", W), vt("bool", W)

    # y = x * alpha + lane (uniform param, broadcast, lane)
    def affine(b, a, mask):
        al = b.op(Op.BROADCAST, f, a["alpha"])
        lane = b.op(Op.CAST, f, b.op(Op.LANE, i32))
        return [b.op(Op.ADD, f, b.op(Op.MUL, f, a["x"], al), lane)]
    add_kernel(m, "affine", [("x", "f32", "varying"), ("alpha", "f32", "uniform", 2.0)], affine)

    # uniform IF on any(x > 0): then 2x else -x; plus a uniform result
    def branch(b, a, mask):
        x = a["x"]
        pos = b.op(Op.GT, bl, x, b.op(Op.BROADCAST, f, b.const(0.0, ir.F32)))
        pos = b.op(Op.AND, bl, pos, mask)
        c = b.op(Op.ANY, ir.BOOL, pos)
        then_r, else_r = ir.Block(), ir.Block()
        tb = ir.Builder(then_r)
        tb.yield_(tb.op(Op.ADD, f, x, x), tb.const(1, ir.I32))
        eb = ir.Builder(else_r)
        eb.yield_(eb.op(Op.NEG, f, x), eb.const(0, ir.I32))
        ins = b.emit(Op.IF, [c], [f, ir.I32], regions=[then_r, else_r])
        return list(ins.results)
    add_kernel(m, "branch", [("x", "f32", "varying")], branch, ["ret.0", "ret.1"])

    # masked loop: count halvings of x until x < 1 (per lane), max 64 iterations
    def halvings(b, a, mask):
        x0 = a["x"]
        body = ir.Block([ir.Value(f, "x"), ir.Value(i32, "k"), ir.Value(bl, "active")])
        x, k, active = body.args
        lb = ir.Builder(body)
        one = lb.op(Op.BROADCAST, f, lb.const(1.0, ir.F32))
        go = lb.op(Op.AND, bl, active, lb.op(Op.GE, bl, x, one))
        half = lb.op(Op.MUL, f, x, lb.op(Op.BROADCAST, f, lb.const(0.5, ir.F32)))
        x1 = lb.op(Op.SELECT, f, go, half, x)
        k1 = lb.op(Op.SELECT, i32, go, lb.op(Op.ADD, i32, k, lb.op(Op.BROADCAST, i32,
                                                                   lb.const(1, ir.I32))), k)
        cap = lb.op(Op.LT, bl, k1, lb.op(Op.BROADCAST, i32, lb.const(64, ir.I32)))
        go = lb.op(Op.AND, bl, go, cap)
        lb.yield_(lb.op(Op.ANY, ir.BOOL, go), x1, k1, go)
        zero = b.op(Op.BROADCAST, i32, b.const(0, ir.I32))
        loop = b.emit(Op.LOOP, [x0, zero, mask], [f, i32, bl], regions=[body])
        return [loop.results[1]]
    add_kernel(m, "halvings", [("x", "f32", "varying")], halvings)

    # gather table[idx] where idx in range, scatter x into out[idx]; load/store uniform
    def gather(b, a, mask):
        idx = a["idx"]
        ok = b.op(Op.AND, bl, mask, b.op(Op.LT, bl, idx, b.op(Op.BROADCAST, i32,
                                                              a["size"])))
        g = b.op(Op.GATHER, f, a["table"], idx, ok)
        b.emit(Op.SCATTER, [a["out"], idx, a["x"], ok], [])
        first = b.op(Op.LOAD, ir.F32, a["table"], b.const(0, ir.I32))
        b.emit(Op.STORE, [a["table"], b.const(10, ir.U64), first], [])
        return [g]
    add_kernel(m, "gather", [("table", "f32", "buffer"), ("out", "f32", "buffer"),
                             ("idx", "i32", "varying"), ("x", "f32", "varying"),
                             ("size", "i32", "uniform", 0)], gather)

    # bool and u64 in/out, a uniform bool param
    def logic(b, a, mask):
        flip = b.op(Op.BROADCAST, bl, a["flip"])
        return [b.op(Op.XOR, bl, a["p"], flip), b.op(Op.ADD, vt("u64", W), a["w"], a["w"])]
    add_kernel(m, "logic", [("p", "bool", "varying"), ("w", "u64", "varying"),
                            ("flip", "bool", "uniform", False)], logic, ["ret.0", "ret.1"])

    def void(b, a, mask):
        b.emit(Op.SCATTER, [a["buf"], b.op(Op.LANE, i32), a["x"], mask], [])
        return []
    add_kernel(m, "void", [("buf", "f32", "buffer"), ("x", "f32", "varying")], void)
    return m


@pytest.fixture(scope="module", params=runnable_targets())
def lib(request, tmp_path_factory):
    t = get_target(request.param)
    return build_and_load(_features_module(t.width), t.name, tmp_path_factory.mktemp(t.name))


@pytest.mark.parametrize("n", [0, 1, 3, 4, 7, 8, 15, 16, 17, 33, 100])
def test_tail_and_lane(lib, n):
    x = np.arange(n, dtype=np.float32) * 0.25
    got = lib.affine(x, alpha=3.0)
    lane = (np.arange(n) % lib.width).astype(np.float32)
    np.testing.assert_array_equal(got, x * np.float32(3.0) + lane)
    np.testing.assert_array_equal(lib.affine(x), x * np.float32(2.0) + lane)  # default


@pytest.mark.parametrize("n", [1, 5, 16, 37])
def test_user_mask_leaves_outputs(lib, n):
    x = np.arange(n, dtype=np.float32)
    mask = np.arange(n) % 3 != 1
    got = lib.affine(x, mask=mask, alpha=1.0)
    lane = (np.arange(n) % lib.width).astype(np.float32)
    np.testing.assert_array_equal(got[mask], (x + lane)[mask])
    assert (got[~mask] == 0).all()  # never written: the runtime zero-fills when masked


def test_if_uniform_condition(lib):
    W = lib.width
    x = np.array([-1, -2, 3, -4] * 8 + [-5, -6, -7], dtype=np.float32)
    v, flag = lib.branch(x)
    n = len(x)
    for s in range(0, n, W):
        blk = x[s:s + W]
        if (blk > 0).any():
            np.testing.assert_array_equal(v[s:s + W], blk * 2)
            assert (flag[s:s + W] == 1).all()
        else:
            np.testing.assert_array_equal(v[s:s + W], -blk)
            assert (flag[s:s + W] == 0).all()


def test_loop(lib):
    x = np.array([0.5, 1.0, 3.0, 1e6, 0.0, np.inf, np.nan, 1024.0] * 5 + [7.0],
                 dtype=np.float32)
    expected = []
    for v in x.tolist():
        k = 0
        while v >= 1.0 and k < 64:
            v *= 0.5
            k += 1
        expected.append(k)
    np.testing.assert_array_equal(lib.halvings(x), np.array(expected, dtype=np.int32))
    mask = np.arange(len(x)) % 2 == 0
    np.testing.assert_array_equal(lib.halvings(x, mask=mask)[mask],
                                  np.array(expected, dtype=np.int32)[mask])


def test_gather_scatter(lib):
    n = 45
    table = np.arange(11, dtype=np.float32) + 100  # element 10: written by the kernel
    out = np.zeros(10, dtype=np.float32)
    idx = (np.arange(n, dtype=np.int32) * 7) % 13  # 10, 11, 12 are out of range
    x = np.arange(n, dtype=np.float32)
    g = lib.gather(table, out, idx, x, size=10)
    ok = idx < 10
    np.testing.assert_array_equal(g[ok], 100 + idx[ok].astype(np.float32))
    assert (g[~ok] == 0).all()
    expected = np.zeros(10, dtype=np.float32)
    for i in range(n):  # lane order: the last writer wins
        if ok[i]:
            expected[idx[i]] = x[i]
    np.testing.assert_array_equal(out, expected)
    assert table[10] == 100.0  # store of load(table, 0) into element 10


@pytest.mark.parametrize("step", [1, 0])
@pytest.mark.parametrize("start", [0, 3, 16, 39])
def test_gather_of_consecutive_or_equal_indices(lib, start, step):
    """Lanes reading consecutive elements (or one element) take a masked vector load (or a
    broadcast load) instead of a gather: the same values, masked lanes (index out of range)
    included."""
    n = 45
    table = np.arange(64, dtype=np.float32) + 100
    idx = (start + step * np.arange(n)).astype(np.int32)
    idx[20] = 7  # one vector with a lane out of step
    idx[32] = 60  # one whose lane 0 is masked
    g = lib.gather(table, np.zeros(64, np.float32), idx, np.zeros(n, np.float32), size=40)
    ok = idx < 40
    seen = ok & (idx != 10)  # the kernel stores table[0] into table[10] after each vector
    np.testing.assert_array_equal(g[seen], 100 + idx[seen].astype(np.float32))
    assert (g[~ok] == 0).all()


def test_bool_u64_and_uniform_bool(lib):
    p = np.array([True, False, True] * 11)
    w = np.arange(33, dtype=np.uint64) + np.uint64(2**63 - 5)
    r, s = lib.logic(p, w)
    np.testing.assert_array_equal(r, p)
    assert r.dtype == np.bool_
    np.testing.assert_array_equal(s, w + w)
    r, _ = lib.logic(p, w, flip=True)
    np.testing.assert_array_equal(r, ~p)


def test_void_kernel(lib):
    buf = np.zeros(16, dtype=np.float32)
    n = lib.width  # one vector: lane i writes buf[i]
    assert lib.void(buf, np.arange(n, dtype=np.float32) + 1) is None
    np.testing.assert_array_equal(buf[:n], np.arange(n) + 1)


# --------------------------------------------------------------------------------------
# Emission and targets


def _small(width: int) -> ir.Module:
    m = new_module(width)
    add_kernel(m, "scale", [("x", "f32", "varying"), ("s", "f32", "uniform", 1.0)],
               lambda b, a, mask: [b.op(Op.MUL, vt("f32", width), a["x"],
                                        b.op(Op.BROADCAST, vt("f32", width), a["s"]))])
    return m


def test_emit_asm_avx512_uses_zmm():
    asm = llvm_backend.emit_asm(_small(16), "avx512")
    assert "zmm" in asm
    assert "rdsl_scale_range" in asm


def test_emit_llvm_and_object():
    text = llvm_backend.emit_llvm(_small(8), "avx2")
    assert "define void @rdsl_scale(" in text and "<8 x float>" in text
    assert "fast" not in text.split("attributes")[0].replace("fastcc", "")
    obj = llvm_backend.emit_object(_small(4), "sse4")
    assert obj[:4] == b"\x7fELF"
    sigs = llvm_backend.kernel_signatures(_small(1))
    assert sigs["scale"] == ("void rdsl_scale(int64_t n, const float* x, int64_t x_stride, "
                             "float s, float* out_ret, int64_t out_ret_stride, "
                             "const uint8_t* mask, int64_t mask_stride)")


def test_width_mismatch_is_a_compile_error():
    with pytest.raises(CompileError, match="width 8"):
        llvm_backend.emit_llvm(_small(8), "sse4")


def test_unsupported_op_is_a_diagnostic():
    m = new_module(4)
    loc = ir.Loc("bad.rdsl", 3, 5)

    def body(b, a, mask):
        return [b.emit(Op.CALL, [a["x"]], [vt("f32", 4)], {"callee": "f"}, loc=loc).result]
    add_kernel(m, "k", [("x", "f32", "varying")], body)
    with pytest.raises(CompileError, match=r"bad.rdsl:3:5: error: .*`call`"):
        llvm_backend.emit_llvm(m, "sse4")


def test_targets():
    assert [TARGETS[n].width for n in ("scalar", "sse4", "avx2", "avx512")] == [1, 4, 8, 16]
    assert host_supports("scalar")
    assert host_supports(host_target())
    assert get_target("host") == host_target()
    with pytest.raises(CompileError, match="valid targets: scalar, sse4, avx2, avx512, host"):
        get_target("neon")


def test_unwritable_out_dir(tmp_path: Path):
    from rdsl.compiler.backends.clib import build_library

    blocker = tmp_path / "file"
    blocker.write_text("keep me")
    with pytest.raises(CompileError, match="cannot write to output directory"):
        build_library(_small(1), "scalar", blocker / "sub", "k")
    assert blocker.read_text() == "keep me"
