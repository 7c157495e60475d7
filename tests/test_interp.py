"""The reference interpreter against hand-computed and numpy values (docs/ir.md semantics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rdsl.compiler.interp import InterpError, StepLimitExceeded, int_to_f32, run_function
from rdsl.compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    U64,
    VEC3,
    Block,
    BufferType,
    Builder,
    Function,
    Module,
    Op,
    Param,
    StructType,
    Type,
    Value,
)

INT_MIN, INT_MAX = -(2**31), 2**31 - 1


def bits(x) -> int:
    return int(np.float32(x).view(np.uint32))


def func(m: Module, name: str, params: list[Type], rets: list[Type], build) -> Function:
    """Add a function whose body is ``return build(builder, *params)``."""
    fn = m.add(Function(name, [Param(Value(t, f"p{i}")) for i, t in enumerate(params)],
                        rets, Block()))
    b = Builder(fn.body)
    out = build(b, *[p.value for p in fn.params])
    b.return_(*(out if isinstance(out, (list, tuple)) else [out]))
    return fn


def run1(op: Op, rt: Type, args: list, types: list[Type], **attrs):
    """Run a single instruction on the given arguments."""
    m = Module()
    func(m, "f", types, [rt], lambda b, *ps: b.op(op, rt, *ps, **attrs))
    return run_function(m, "f", args)[0]


def binop(op: Op, t: Type, a, b):
    return run1(op, t, [a, b], [t, t])


def test_f32_arithmetic_is_float32_not_float64():
    r = binop(Op.ADD, F32, 0.1, 0.2)
    assert isinstance(r, np.float32)
    assert bits(r) == bits(np.float32(0.1) + np.float32(0.2))
    # (1e8 + 1) - 1e8: 0 in f32 (1e8 + 1 rounds back to 1e8), 1 if f64 leaked
    m = Module()
    func(m, "f", [F32, F32], [F32],
         lambda b, x, y: b.op(Op.SUB, F32, b.op(Op.ADD, F32, x, y), x))
    assert run_function(m, "f", [1e8, 1.0])[0] == 0.0
    assert bits(binop(Op.DIV, F32, 1.0, 3.0)) == bits(np.float32(1) / np.float32(3))
    assert bits(binop(Op.MUL, F32, 1e30, 1e30)) == bits(np.float32("inf"))
    assert binop(Op.MUL, F32, 1e-30, 1e-10) != 0.0  # denormals are kept
    assert math.isnan(binop(Op.DIV, F32, 0.0, 0.0))


def test_float_rem_is_fmod():
    assert binop(Op.REM, F32, -5.5, 2.0) == -1.5
    assert binop(Op.REM, F32, 5.0, -3.0) == 2.0
    assert bits(binop(Op.REM, F32, -4.0, 2.0)) == bits(-0.0)
    assert math.isnan(binop(Op.REM, F32, 1.0, 0.0))
    assert binop(Op.REM, F32, 1.5, float("inf")) == 1.5


@pytest.mark.parametrize("op,a,b,want", [
    (Op.ADD, INT_MAX, 1, INT_MIN),
    (Op.SUB, INT_MIN, 1, INT_MAX),
    (Op.MUL, 65536, 65536, 0),
    (Op.DIV, 7, 0, 0),
    (Op.REM, 7, 0, 0),
    (Op.DIV, INT_MIN, -1, INT_MIN),
    (Op.REM, INT_MIN, -1, 0),
    (Op.DIV, -7, 2, -3),
    (Op.REM, -7, 2, -1),
    (Op.REM, 7, -2, 1),
    (Op.SHL, 1, 33, 2),
    (Op.SHL, 1, -1, INT_MIN),
    (Op.SHR, -8, 1, -4),
    (Op.SHR, INT_MIN, 31, -1),
    (Op.AND, -1, 0x0F0, 0x0F0),
    (Op.XOR, -1, 1, -2),
    (Op.MIN, -1, 1, -1),
    (Op.MAX, -1, 1, 1),
])
def test_i32_ops(op, a, b, want):
    r = binop(op, I32, a, b)
    assert isinstance(r, np.int32) and int(r) == want


@pytest.mark.parametrize("t,op,a,b,want", [
    (U32, Op.SUB, 0, 1, 0xFFFF_FFFF),
    (U32, Op.SHR, 0x8000_0000, 1, 0x4000_0000),
    (U32, Op.SHR, 0x8000_0000, 32, 0x8000_0000),
    (U32, Op.DIV, 0xFFFF_FFFF, 2, 0x7FFF_FFFF),
    (U32, Op.MIN, 0xFFFF_FFFF, 1, 1),
    (U64, Op.SHL, 1, 63, 1 << 63),
    (U64, Op.SHL, 1, 64, 1),
    (U64, Op.ADD, 2**64 - 1, 2, 1),
    (U64, Op.MUL, 2**63, 2, 0),
    (U64, Op.REM, 2**64 - 1, 0, 0),
])
def test_unsigned_ops(t, op, a, b, want):
    assert int(binop(op, t, a, b)) == want


def test_unary_int_and_bool():
    assert int(run1(Op.NEG, I32, [INT_MIN], [I32])) == INT_MIN
    assert int(run1(Op.ABS, I32, [INT_MIN], [I32])) == INT_MIN
    assert int(run1(Op.ABS, I32, [-5], [I32])) == 5
    assert int(run1(Op.NOT, U32, [0], [U32])) == 0xFFFF_FFFF
    assert int(run1(Op.NEG, U32, [1], [U32])) == 0xFFFF_FFFF
    assert run1(Op.NOT, BOOL, [True], [BOOL]) is False
    assert binop(Op.XOR, BOOL, True, True) is False
    assert binop(Op.OR, BOOL, False, True) is True


def test_float_sign_ops_use_bits():
    assert bits(run1(Op.ABS, F32, [-0.0], [F32])) == 0
    neg_nan = np.uint32(0xFFC0_0001).view(np.float32)
    assert bits(run1(Op.ABS, F32, [neg_nan], [F32])) == 0x7FC0_0001
    assert bits(run1(Op.NEG, F32, [0.0], [F32])) == 0x8000_0000
    assert bits(run1(Op.NEG, F32, [neg_nan], [F32])) == 0x7FC0_0001
    assert run1(Op.SQRT, F32, [2.0], [F32]) == np.sqrt(np.float32(2.0))
    assert math.isnan(run1(Op.SQRT, F32, [-1.0], [F32]))
    assert run1(Op.FLOOR, F32, [-0.5], [F32]) == -1.0
    assert bits(run1(Op.CEIL, F32, [-0.5], [F32])) == 0x8000_0000


def test_nan_comparisons():
    nan = float("nan")
    for op in (Op.EQ, Op.LT, Op.LE, Op.GT, Op.GE):
        assert run1(op, BOOL, [nan, 1.0], [F32, F32]) is False
        assert run1(op, BOOL, [nan, nan], [F32, F32]) is False
    assert run1(Op.NE, BOOL, [nan, nan], [F32, F32]) is True
    assert run1(Op.EQ, BOOL, [0.0, -0.0], [F32, F32]) is True
    # signed vs unsigned comparison
    assert run1(Op.LT, BOOL, [-1, 0], [I32, I32]) is True
    assert run1(Op.LT, BOOL, [0xFFFF_FFFF, 0], [U32, U32]) is False


def test_min_max_are_selects():
    nan = float("nan")
    assert binop(Op.MIN, F32, nan, 1.0) == 1.0
    assert math.isnan(binop(Op.MIN, F32, 1.0, nan))
    assert binop(Op.MAX, F32, nan, 1.0) == 1.0
    assert math.isnan(binop(Op.MAX, F32, 1.0, nan))
    assert bits(binop(Op.MIN, F32, -0.0, 0.0)) == 0
    assert bits(binop(Op.MIN, F32, 0.0, -0.0)) == 0x8000_0000
    assert bits(binop(Op.MAX, F32, 0.0, -0.0)) == 0x8000_0000


def cast(x, src: Type, dst: Type):
    return run1(Op.CAST, dst, [x], [src])


@pytest.mark.parametrize("x,dst,want", [
    (3e9, I32, INT_MAX), (-3e9, I32, INT_MIN), (float("nan"), I32, 0), (-1.5, I32, -1),
    (1.99, I32, 1), (float("inf"), I32, INT_MAX), (float("-inf"), I32, INT_MIN),
    (-1.0, U32, 0), (5e9, U32, 0xFFFF_FFFF), (float("nan"), U32, 0),
    (1e20, U64, 2**64 - 1), (-0.5, U64, 0), (16777216.0, U64, 16777216),
])
def test_float_to_int_casts_saturate(x, dst, want):
    assert int(cast(x, F32, dst)) == want


def test_int_casts():
    assert int(cast(-1, I32, U64)) == 2**64 - 1  # sign-extends
    assert int(cast(0xFFFF_FFFF, U32, U64)) == 0xFFFF_FFFF  # zero-extends
    assert int(cast(0x1_8000_0001, U64, I32)) == INT_MIN + 1  # truncates
    assert int(cast(0x1_0000_0005, U64, U32)) == 5
    assert int(cast(-1, I32, U32)) == 0xFFFF_FFFF
    assert int(cast(0x8000_0000, U32, I32)) == INT_MIN
    assert cast(True, BOOL, I32) == 1 and cast(False, BOOL, F32) == 0.0
    assert cast(2, I32, BOOL) is True and cast(0, U64, BOOL) is False
    assert cast(float("nan"), F32, BOOL) is True
    assert cast(-0.0, F32, BOOL) is False


def test_int_to_f32_rounds_once():
    assert cast(16777217, I32, F32) == 16777216.0
    assert cast(16777219, I32, F32) == 16777220.0
    assert cast(INT_MIN, I32, F32) == -2147483648.0
    assert cast(0xFFFF_FFFF, U32, F32) == 4294967296.0
    x = (1 << 60) + (1 << 36) + 1  # f64 would round to a tie, then to even: wrong
    assert cast(x, U64, F32) == np.uint64(x).astype(np.float32)
    assert int(cast(x, U64, F32)) == (1 << 60) + (1 << 37)
    for v in (2**64 - 1, 2**63 + 2**39, 2**63 + 2**39 + 1, 12345678901234567):
        assert int_to_f32(v) == np.uint64(v).astype(np.float32)


def test_bitcast():
    assert int(run1(Op.BITCAST, U32, [1.0], [F32])) == 0x3F80_0000
    assert int(run1(Op.BITCAST, I32, [-0.0], [F32])) == INT_MIN
    r = run1(Op.BITCAST, F32, [0x7FC0_0001], [U32])
    assert bits(r) == 0x7FC0_0001
    assert bits(run1(Op.BITCAST, F32, [-1], [I32])) == 0xFFFF_FFFF


def test_select():
    assert binop(Op.MIN, I32, 3, 4) == 3
    m = Module()
    func(m, "f", [BOOL, F32, F32], [F32], lambda b, c, x, y: b.op(Op.SELECT, F32, c, x, y))
    assert run_function(m, "f", [True, 1.0, 2.0])[0] == 1.0
    assert run_function(m, "f", [False, 1.0, 2.0])[0] == 2.0


def count_loop(m: Module, acc_type: Type) -> None:
    """sum(i for i in range(n)) as a do-while loop guarded by an if."""
    def build(b: Builder, n):
        zero = b.const(0, I32)
        body = Block([Value(I32, "i"), Value(acc_type, "acc")])
        bb = Builder(body)
        i, acc = body.args
        x = bb.op(Op.CAST, acc_type, i) if acc_type != I32 else i
        acc1 = bb.op(Op.ADD, acc_type, acc, x)
        i1 = bb.op(Op.ADD, I32, i, bb.const(1, I32))
        bb.yield_(bb.op(Op.LT, BOOL, i1, n), i1, acc1)
        then, els = Block(), Block()
        tb = Builder(then)
        loop = tb.emit(Op.LOOP, [zero, tb.const(0, acc_type)], [I32, acc_type], regions=[body])
        tb.yield_(loop.results[1])
        eb = Builder(els)
        eb.yield_(eb.const(0, acc_type))
        cond = b.op(Op.GT, BOOL, n, zero)
        return b.emit(Op.IF, [cond], [acc_type], regions=[then, els]).result

    func(m, "sum_" + str(acc_type), [I32], [acc_type], build)


def test_loops():
    m = Module()
    count_loop(m, I32)
    count_loop(m, F32)
    assert run_function(m, "sum_i32", [10])[0] == 45
    assert run_function(m, "sum_i32", [0])[0] == 0
    assert run_function(m, "sum_i32", [-3])[0] == 0
    want = np.float32(0)
    for i in range(5000):
        want = np.float32(want + np.float32(i))
    assert bits(run_function(m, "sum_f32", [5000])[0]) == bits(want)
    total = (100000 * 99999 // 2 + 2**31) % 2**32 - 2**31  # wraps
    assert run_function(m, "sum_i32", [100000])[0] == total


def test_nested_ifs_sign():
    def build(b: Builder, x):
        zero = b.const(0.0, F32)
        inner_t, inner_e = Block(), Block()
        Builder(inner_t).yield_(Builder(inner_t).const(-1, I32))
        ib = Builder(inner_e)
        ib.yield_(ib.const(0, I32))  # zero or NaN
        outer_t, outer_e = Block(), Block()
        Builder(outer_t).yield_(Builder(outer_t).const(1, I32))
        eb = Builder(outer_e)
        inner = eb.emit(Op.IF, [eb.op(Op.LT, BOOL, x, zero)], [I32], regions=[inner_t, inner_e])
        eb.yield_(inner.result)
        return b.emit(Op.IF, [b.op(Op.GT, BOOL, x, zero)], [I32],
                      regions=[outer_t, outer_e]).result

    m = Module()
    func(m, "sign", [F32], [I32], build)
    for x, want in [(2.0, 1), (-2.0, -1), (0.0, 0), (-0.0, 0), (float("nan"), 0)]:
        assert run_function(m, "sign", [x])[0] == want


def test_load_store_and_call():
    m = Module()
    func(m, "twice", [F32], [F32], lambda b, x: b.op(Op.MUL, F32, x, b.const(2.0, F32)))

    def build(b: Builder, buf, i):
        v = b.op(Op.LOAD, F32, buf, i)
        r = b.emit(Op.CALL, [v], [F32], {"callee": "twice"}).result
        b.emit(Op.STORE, [buf, i, r], [])
        return []

    func(m, "scale", [BufferType(F32), I32], [], build)
    arr = np.array([1.0, 2.5, 3.0], dtype=np.float32)
    assert run_function(m, "scale", [arr, 1]) == []
    assert arr.tolist() == [1.0, 5.0, 3.0]
    ints = np.array([7, 8], dtype=np.uint32)
    m2 = Module()
    func(m2, "ld", [BufferType(U32), I32], [U32], lambda b, buf, i: b.op(Op.LOAD, U32, buf, i))
    r = run_function(m2, "ld", [ints, 1])[0]
    assert isinstance(r, np.uint32) and r == 8


def test_aggregates():
    S = StructType("S", (("v", VEC3), ("w", F32)))
    m = Module(structs={"S": S})

    def build(b: Builder, a, x):
        v = b.op(Op.ADD, VEC3, a, b.op(Op.BROADCAST, VEC3, x))
        v = b.op(Op.INSERT, VEC3, v, x, index=2)
        s = b.op(Op.MAKE, S, v, b.op(Op.EXTRACT, F32, v, index=0))
        return [s, b.op(Op.NEG, VEC3, a)]

    func(m, "f", [VEC3, F32], [S, VEC3], build)
    s, n = run_function(m, "f", [(1.0, 2.0, 3.0), 0.5])
    assert s == ((1.5, 2.5, 0.5), 1.5)
    assert all(isinstance(c, np.float32) for c in s[0])
    assert bits(n[0]) == bits(-1.0) and len(n) == 3


def test_infinite_loop_hits_step_limit():
    m = Module()

    def build(b: Builder, x):
        body = Block([Value(F32, "x")])
        bb = Builder(body)
        bb.yield_(bb.const(True, BOOL), body.args[0])
        return b.emit(Op.LOOP, [x], [F32], regions=[body]).result

    func(m, "spin", [F32], [F32], build)
    with pytest.raises(StepLimitExceeded):
        run_function(m, "spin", [1.0], step_limit=10_000)


def test_unsupported_inputs_raise():
    m = Module()
    func(m, "s", [SPECTRUM], [SPECTRUM], lambda b, s: b.op(Op.ADD, SPECTRUM, s, s))
    with pytest.raises(InterpError, match="spectrum"):
        run_function(m, "s", [(1.0, 2.0)])
    func(m, "f", [F32], [F32], lambda b, x: x)
    with pytest.raises(InterpError, match="takes 1 argument"):
        run_function(m, "f", [])
    with pytest.raises(InterpError, match="no function"):
        run_function(m, "nope", [])
