"""The optimize pass: each rewrite fires, and differential equivalence on random inputs and on
random programs (interpret before and after, compare bit for bit)."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rdsl.compiler.interp import run_function
from rdsl.compiler.ir import (
    BOOL,
    F32,
    I32,
    U32,
    VEC3,
    Block,
    BufferType,
    Builder,
    Function,
    Module,
    Op,
    Param,
    ScalarType,
    Type,
    Value,
)
from rdsl.compiler.irparse import parse_module
from rdsl.compiler.passes import REGISTRY
from rdsl.compiler.passes.optimize import Optimize
from rdsl.compiler.printer import print_module
from rdsl.compiler.verify import verify

INT_MIN, INT_MAX = -(2**31), 2**31 - 1
NAN, INF = float("nan"), float("inf")


def func(m: Module, name: str, params: list[Type], rets: list[Type], build, **attrs) -> Function:
    fn = m.add(Function(name, [Param(Value(t, f"p{i}")) for i, t in enumerate(params)],
                        rets, Block(), attrs=attrs))
    b = Builder(fn.body)
    out = build(b, *[p.value for p in fn.params])
    b.return_(*(out if isinstance(out, (list, tuple)) else [out]))
    return fn


def optimized(m: Module) -> Module:
    """A copy of ``m`` (via the textual form), optimized and verified."""
    copy = parse_module(print_module(m))
    Optimize().run(copy)
    verify(copy)
    return copy


def body_ops(m: Module, name: str = "f") -> list[str]:
    return [ins.op.value for ins in m.functions[name].walk()]


def single(params, rets, build) -> Module:
    m = Module()
    func(m, "f", params, rets, build)
    verify(m)
    return m


def same(a, b) -> bool:
    """Bitwise equality, except that any NaN equals any NaN (IEEE lets x*1 quiet a NaN)."""
    if isinstance(a, tuple):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.float32):
        if math.isnan(a):
            return bool(np.isnan(b))
        return int(a.view(np.uint32)) == int(np.float32(b).view(np.uint32))
    return type(a) is type(b) and a == b


def assert_equivalent(m: Module, m2: Module, name: str, args: list) -> None:
    want = run_function(m, name, args)
    got = run_function(m2, name, args)
    assert len(want) == len(got) and all(same(w, g) for w, g in zip(want, got)), (want, got)


def test_registered():
    assert REGISTRY["optimize"] is Optimize


# --------------------------------------------------------------------------------------
# Individual rewrites


def test_constant_folding_uses_exact_semantics():
    def build(b, x):
        s = b.op(Op.ADD, F32, b.const(0.1, F32), b.const(0.2, F32))
        d = b.op(Op.DIV, I32, b.const(INT_MIN, I32), b.const(-1, I32))
        z = b.op(Op.REM, I32, b.const(7, I32), b.const(0, I32))
        c = b.op(Op.CAST, I32, b.const(NAN, F32))
        n = b.op(Op.NE, BOOL, b.const(NAN, F32), b.const(NAN, F32))
        return [s, d, z, c, n]

    m2 = optimized(single([F32], [F32, I32, I32, I32, BOOL], build))
    consts = [i.attrs["value"] for i in m2.functions["f"].walk() if i.op is Op.CONST]
    assert body_ops(m2) == ["const"] * 4 + ["return"]  # the two zeros are CSE'd
    assert consts[0] == float(np.float32(0.1) + np.float32(0.2))
    assert consts[1:] == [INT_MIN, 0, True]


def test_float_identities():
    def build(b, x):
        one, pz, nz = b.const(1.0, F32), b.const(0.0, F32), b.const(-0.0, F32)
        r = b.op(Op.MUL, F32, x, one)
        r = b.op(Op.MUL, F32, one, r)
        r = b.op(Op.ADD, F32, r, nz)
        r = b.op(Op.SUB, F32, r, pz)
        r = b.op(Op.DIV, F32, r, one)
        return r

    m2 = optimized(single([F32], [F32], build))
    assert body_ops(m2) == ["return"]
    assert m2.functions["f"].body.instrs[-1].operands[0] is m2.functions["f"].params[0].value


def test_illegal_float_identities_are_kept():
    def build(b, x):
        return [b.op(Op.ADD, F32, x, b.const(0.0, F32)),  # -0.0 + 0.0 = +0.0
                b.op(Op.MUL, F32, x, b.const(0.0, F32)),  # inf * 0 = NaN, -1 * 0 = -0
                b.op(Op.SUB, F32, x, x),  # inf - inf = NaN
                b.op(Op.SUB, F32, x, b.const(-0.0, F32))]  # -0.0 - -0.0 = +0.0

    m = single([F32], [F32] * 4, build)
    m2 = optimized(m)
    assert body_ops(m2).count("add") == 1 and body_ops(m2).count("mul") == 1
    assert body_ops(m2).count("sub") == 2
    for x in (-0.0, INF, NAN, -1.0):
        assert_equivalent(m, m2, "f", [x])


def test_integer_identities():
    def build(b, x, y):
        zero, one = b.const(0, I32), b.const(1, I32)
        r = b.op(Op.ADD, I32, x, zero)
        r = b.op(Op.SUB, I32, r, zero)
        r = b.op(Op.MUL, I32, r, one)
        r = b.op(Op.DIV, I32, r, one)
        r = b.op(Op.OR, I32, r, zero)
        r = b.op(Op.XOR, I32, zero, r)
        r = b.op(Op.SHL, I32, r, b.const(32, I32))
        r = b.op(Op.AND, I32, r, b.const(-1, I32))
        z = b.op(Op.MUL, I32, y, zero)
        k = b.op(Op.SUB, I32, y, y)
        e = b.op(Op.EQ, BOOL, y, y)
        return [r, z, k, e]

    m2 = optimized(single([I32, I32], [I32, I32, I32, BOOL], build))
    fn = m2.functions["f"]
    ret = fn.body.instrs[-1]
    assert ret.operands[0] is fn.params[0].value
    assert [i.attrs["value"] for i in fn.walk() if i.op is Op.CONST] == [0, True]
    assert body_ops(m2) == ["const", "const", "return"]


def test_bool_identities_and_select():
    def build(b, c, d, x, y):
        t, f = b.const(True, BOOL), b.const(False, BOOL)
        r1 = b.op(Op.AND, BOOL, c, t)  # c
        r2 = b.op(Op.OR, BOOL, f, d)  # d
        r3 = b.op(Op.AND, BOOL, c, f)  # false
        r4 = b.op(Op.OR, BOOL, t, d)  # true
        r5 = b.op(Op.NOT, BOOL, b.op(Op.NOT, BOOL, c))  # c
        s1 = b.op(Op.SELECT, F32, t, x, y)  # x
        s2 = b.op(Op.SELECT, F32, c, y, y)  # y
        s3 = b.op(Op.SELECT, BOOL, d, t, f)  # d
        n = b.op(Op.NEG, F32, b.op(Op.NEG, F32, x))  # x
        return [r1, r2, r3, r4, r5, s1, s2, s3, n]

    m2 = optimized(single([BOOL, BOOL, F32, F32], [BOOL] * 5 + [F32, F32, BOOL, F32], build))
    fn = m2.functions["f"]
    c, d, x, y = (p.value for p in fn.params)
    ret = fn.body.instrs[-1].operands
    assert [ret[i] for i in (0, 1, 4, 5, 6, 7, 8)] == [c, d, c, x, y, d, x]
    assert [ret[i].owner.attrs["value"] for i in (2, 3)] == [False, True]
    assert body_ops(m2) == ["const", "const", "return"]


def test_extract_forwarding():
    def build(b, x, y, v):
        mk = b.op(Op.MAKE, VEC3, x, y, x)
        e1 = b.op(Op.EXTRACT, F32, mk, index=1)  # y
        ins = b.op(Op.INSERT, VEC3, v, x, index=0)
        e2 = b.op(Op.EXTRACT, F32, ins, index=0)  # x
        e3 = b.op(Op.EXTRACT, F32, ins, index=2)  # extract v[2]
        bc = b.op(Op.BROADCAST, VEC3, y)
        e4 = b.op(Op.EXTRACT, F32, bc, index=2)  # y
        return [e1, e2, e3, e4]

    m = single([F32, F32, VEC3], [F32] * 4, build)
    m2 = optimized(m)
    fn = m2.functions["f"]
    x, y, v = (p.value for p in fn.params)
    ret = fn.body.instrs[-1].operands
    assert ret[0] is y and ret[1] is x and ret[3] is y
    assert ret[2].owner.op is Op.EXTRACT and ret[2].owner.operands[0] is v
    assert body_ops(m2) == ["extract", "return"]
    assert_equivalent(m, m2, "f", [1.0, 2.0, (3.0, 4.0, 5.0)])


def if_(b: Builder, cond: Value, types, then_fn, else_fn):
    t, e = Block(), Block()
    tb, eb = Builder(t), Builder(e)
    tb.yield_(*then_fn(tb))
    eb.yield_(*else_fn(eb))
    return b.emit(Op.IF, [cond], list(types), regions=[t, e])


def test_if_with_constant_condition_is_inlined():
    def build(b, x):
        cond = b.op(Op.LT, BOOL, b.const(1, I32), b.const(2, I32))
        r = if_(b, cond, [F32], lambda tb: [tb.op(Op.SQRT, F32, x)],
                lambda eb: [eb.op(Op.NEG, F32, x)])
        return r.result

    m = single([F32], [F32], build)
    m2 = optimized(m)
    assert body_ops(m2) == ["sqrt", "return"]
    assert_equivalent(m, m2, "f", [2.0])


def test_trait_constants_are_not_folded():
    def build(b, x):
        cond = b.emit(Op.CONST, [], [BOOL], {"trait": "polarized"}).result
        return if_(b, cond, [F32], lambda tb: [x], lambda eb: [eb.op(Op.NEG, F32, x)]).result

    m2 = optimized(single([F32], [F32], build))
    assert "if" in body_ops(m2)


def counted_loop(b: Builder, n_iter: int, x: Value, body_fn) -> Value:
    """``for i in range(n_iter)`` (at least once): acc = body_fn(builder, acc, i)."""
    body = Block([Value(I32, "i"), Value(F32, "acc")])
    bb = Builder(body)
    i, acc = body.args
    acc1 = body_fn(bb, acc, i)
    i1 = bb.op(Op.ADD, I32, i, bb.const(1, I32))
    bb.yield_(bb.op(Op.LT, BOOL, i1, bb.const(n_iter, I32)), i1, acc1)
    return b.emit(Op.LOOP, [b.const(0, I32), x], [I32, F32], regions=[body]).results[1]


def test_single_iteration_loop_is_inlined():
    def build(b, x):
        return counted_loop(b, 1, x, lambda bb, acc, i: bb.op(Op.MUL, F32, acc, acc))

    m = single([F32], [F32], build)
    m2 = optimized(m)
    assert body_ops(m2) == ["mul", "return"]
    assert_equivalent(m, m2, "f", [3.0])


def test_multi_iteration_loop_is_kept():
    def build(b, x):
        return counted_loop(b, 3, x, lambda bb, acc, i: bb.op(Op.MUL, F32, acc, acc))

    m = single([F32], [F32], build)
    m2 = optimized(m)
    assert "loop" in body_ops(m2)
    assert_equivalent(m, m2, "f", [1.1])


def test_cse_respects_scopes():
    def build(b, x, c):
        a1 = b.op(Op.MUL, F32, x, x)
        a2 = b.op(Op.MUL, F32, x, x)  # same as a1
        r = if_(b, c, [F32, F32],
                lambda tb: [tb.op(Op.MUL, F32, x, x), tb.op(Op.SQRT, F32, x)],  # mul reused
                lambda eb: [eb.op(Op.SQRT, F32, x), x])
        s = b.op(Op.SQRT, F32, x)  # the region's sqrt must not be reused here
        return [b.op(Op.ADD, F32, a1, a2), r.results[0], r.results[1], s]

    m = single([F32, BOOL], [F32] * 4, build)
    m2 = optimized(m)
    ops = body_ops(m2)
    assert ops.count("mul") == 1 and ops.count("sqrt") == 3
    for c in (True, False):
        assert_equivalent(m, m2, "f", [2.0, c])


def test_dce():
    def build(b, x, c, buf):
        b.op(Op.SQRT, F32, x)  # dead
        if_(b, c, [F32], lambda tb: [tb.op(Op.NEG, F32, x)], lambda eb: [x])  # dead if

        def store_then(tb):
            tb.emit(Op.STORE, [buf, tb.const(0, I32), x], [])
            return [tb.op(Op.FLOOR, F32, x), tb.op(Op.CEIL, F32, x)]
        kept = if_(b, c, [F32, F32], store_then, lambda eb: [x, eb.op(Op.ABS, F32, x)])
        counted_loop(b, 4, x, lambda bb, acc, i: bb.op(Op.ADD, F32, acc, x))  # dead loop
        return kept.results[1]

    m = single([F32, BOOL, BufferType(F32)], [F32], build)
    m2 = optimized(m)
    ops = body_ops(m2)
    assert "sqrt" not in ops and "neg" not in ops and "loop" not in ops and "floor" not in ops
    fn = m2.functions["f"]
    ifs = [i for i in fn.walk() if i.op is Op.IF]
    assert len(ifs) == 1 and len(ifs[0].results) == 1  # the unused slot was pruned
    for c in (True, False):
        b1, b2 = np.zeros(1, np.float32), np.zeros(1, np.float32)
        assert same(run_function(m, "f", [-2.5, c, b1])[0], run_function(m2, "f", [-2.5, c, b2])[0])
        assert b1.tolist() == b2.tolist()


def test_dead_loop_slots_are_pruned_but_effects_kept():
    def build(b, x, buf):
        body = Block([Value(I32, "i"), Value(F32, "junk")])
        bb = Builder(body)
        i, junk = body.args
        bb.emit(Op.STORE, [buf, i, x], [])
        i1 = bb.op(Op.ADD, I32, i, bb.const(1, I32))
        bb.yield_(bb.op(Op.LT, BOOL, i1, bb.const(3, I32)), i1, bb.op(Op.ADD, F32, junk, x))
        b.emit(Op.LOOP, [b.const(0, I32), x], [I32, F32], regions=[body])
        return x

    m = single([F32, BufferType(F32)], [F32], build)
    m2 = optimized(m)
    loops = [i for i in m2.functions["f"].walk() if i.op is Op.LOOP]
    assert len(loops) == 1 and [r.type for r in loops[0].results] == [I32]
    assert "add" in body_ops(m2) and body_ops(m2).count("add") == 1
    b1, b2 = np.zeros(4, np.float32), np.zeros(4, np.float32)
    run_function(m, "f", [7.0, b1])
    run_function(m2, "f", [7.0, b2])
    assert b1.tolist() == b2.tolist() == [7.0, 7.0, 7.0, 0.0]


def test_dead_functions_are_removed_only_with_exports():
    m = Module()
    func(m, "used", [F32], [F32], lambda b, x: b.op(Op.NEG, F32, x))
    func(m, "unused", [F32], [F32], lambda b, x: x)
    func(m, "main", [F32], [F32],
         lambda b, x: b.emit(Op.CALL, [x], [F32], {"callee": "used"}).result, export=True)
    m2 = optimized(m)
    assert sorted(m2.functions) == ["main", "used"]
    del m.functions["main"]
    assert sorted(optimized(m).functions) == ["unused", "used"]


def test_signalling_nan_bits_survive():
    def build(b):
        snan = b.op(Op.BITCAST, F32, b.const(0x7F80_0001, U32))
        return b.op(Op.BITCAST, U32, snan)

    m = single([], [U32], build)
    m2 = optimized(m)
    assert int(run_function(m2, "f", [])[0]) == int(run_function(m, "f", [])[0])


def test_optimize_is_idempotent():
    """One sweep (and another only where a sweep says so) reaches the fixed point: a
    second run changes nothing (seeds with nested peeled loops and CSE across a peeled
    body among them)."""
    for seed in range(400):
        m = optimized(random_module(random.Random(seed)))
        text = print_module(m)
        assert print_module(optimized(m)) == text, seed


@pytest.mark.parametrize("plugin", ["bsdf/roughplastic.rdsl", "bsdf/principled.rdsl", "emitter/envmap.rdsl"])
def test_optimize_reaches_a_fixed_point_on_stdlib_kernels(plugin):
    from rdsl.compiler.build import Build
    from rdsl.compiler.driver import STDLIB, frontend, pipeline, run_passes

    m = frontend(STDLIB / plugin)
    run_passes(m, pipeline(Build.of("avx2", "rgb")), verify="ends")
    text = print_module(m)
    assert print_module(optimized(m)) == text


# --------------------------------------------------------------------------------------
# Differential tests

f32s = st.one_of(st.sampled_from([0.0, -0.0, INF, -INF, NAN, 1.0, -1.0, 1e-45, 3.4e38]),
                 st.floats(width=32))
i32s = st.one_of(st.sampled_from([0, 1, -1, 2, 31, 32, INT_MIN, INT_MAX]),
                 st.integers(INT_MIN, INT_MAX))
u32s = st.one_of(st.sampled_from([0, 1, 2, 32, 0x8000_0000, 0xFFFF_FFFF]),
                 st.integers(0, 2**32 - 1))
STRATEGY = {"f32": f32s, "i32": i32s, "u32": u32s, "bool": st.booleans()}
EDGE = {"f32": [0.0, -0.0, 1.0, -1.0, 0.5, 2.0, INF, -INF, NAN, 1e-45, 3.4e38],
        "i32": [0, 1, -1, 2, 31, 32, INT_MIN, INT_MAX],
        "u32": [0, 1, 2, 31, 32, 0x8000_0000, 0xFFFF_FFFF],
        "bool": [True, False]}
PARAMS = [F32, F32, I32, I32, U32, BOOL]
RETS = [F32, F32, I32, U32, BOOL]
BINARY = {"f32": [Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.REM, Op.MIN, Op.MAX],
          "i32": [Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.REM, Op.AND, Op.OR, Op.XOR, Op.SHL,
                  Op.SHR, Op.MIN, Op.MAX],
          "bool": [Op.AND, Op.OR, Op.XOR]}
BINARY["u32"] = BINARY["i32"]
UNARY = {"f32": [Op.NEG, Op.ABS, Op.SQRT, Op.FLOOR, Op.CEIL], "i32": [Op.NEG, Op.NOT, Op.ABS],
         "u32": [Op.NEG, Op.NOT], "bool": [Op.NOT]}
SCALARS = [F32, I32, U32, BOOL]


class _Gen:
    """Random structured programs over f32/i32/u32/bool, biased towards constants and the
    identities the optimizer knows, so that many rewrites fire."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def pick(self, pool: dict[str, list[Value]], t: ScalarType) -> Value:
        return self.rng.choice(pool[t.name])

    def block(self, b: Builder, pool: dict[str, list[Value]], n: int, depth: int) -> None:
        rng = self.rng
        for _ in range(n):
            t = rng.choice(SCALARS)
            k = rng.random()
            if k < 0.2:
                v = b.const(rng.choice(EDGE[t.name]), t)
            elif k < 0.5:
                op = rng.choice(BINARY[t.name])
                v = b.op(op, t, self.pick(pool, t), self.pick(pool, t))
            elif k < 0.6:
                v = b.op(rng.choice(UNARY[t.name]), t, self.pick(pool, t))
            elif k < 0.7:
                s = rng.choice(SCALARS)
                op = rng.choice([Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE])
                v, t = b.op(op, BOOL, self.pick(pool, s), self.pick(pool, s)), BOOL
            elif k < 0.77:
                v = b.op(Op.SELECT, t, self.pick(pool, BOOL), self.pick(pool, t),
                         self.pick(pool, t))
            elif k < 0.84:
                s = rng.choice(SCALARS)
                v = b.op(Op.CAST, t, self.pick(pool, s))
            elif k < 0.87:
                src, t = rng.choice([(F32, I32), (F32, U32), (I32, F32), (U32, F32)])
                v = b.op(Op.BITCAST, t, self.pick(pool, src))
            elif k < 0.9:
                vec = b.op(Op.MAKE, VEC3, *(self.pick(pool, F32) for _ in range(3)))
                if rng.random() < 0.5:
                    vec = b.op(Op.INSERT, VEC3, vec, self.pick(pool, F32), index=rng.randrange(3))
                v, t = b.op(Op.EXTRACT, F32, vec, index=rng.randrange(3)), F32
            elif k < 0.95 and depth < 2:
                v, t = self.if_(b, pool, depth), F32
            elif depth < 2:
                v, t = self.loop(b, pool, depth), F32
            else:
                continue
            pool[t.name].append(v)

    def region(self, pool, depth, yields: list[ScalarType], args=()) -> Block:
        blk = Block(list(args))
        inner = {k: list(v) for k, v in pool.items()}
        for a in args:
            inner[a.type.name].append(a)
        bb = Builder(blk)
        self.block(bb, inner, self.rng.randrange(1, 6), depth + 1)
        return blk, bb, inner

    def if_(self, b: Builder, pool, depth) -> Value:
        regions = []
        for _ in range(2):
            blk, bb, inner = self.region(pool, depth, [F32])
            bb.yield_(inner["f32"][-1], inner["i32"][-1])
            regions.append(blk)
        cond = self.pick(pool, BOOL)
        return b.emit(Op.IF, [cond], [F32, I32], regions=regions).results[self.rng.randrange(1)]

    def loop(self, b: Builder, pool, depth) -> Value:
        args = [Value(I32, "i"), Value(F32, "acc")]
        blk, bb, inner = self.region(pool, depth, [], args)
        i1 = bb.op(Op.ADD, I32, args[0], bb.const(1, I32))
        limit = bb.const(self.rng.choice([0, 1, 2, 5]), I32)
        bb.yield_(bb.op(Op.LT, BOOL, i1, limit), i1, inner["f32"][-1])
        init = b.const(self.rng.choice([0, 0, 1]), I32)
        return b.emit(Op.LOOP, [init, self.pick(pool, F32)], [I32, F32], regions=[blk]).results[1]


def random_module(rng: random.Random) -> Module:
    m = Module()

    def build(b: Builder, *params):
        pool: dict[str, list[Value]] = {"f32": [], "i32": [], "u32": [], "bool": []}
        for p in params:
            pool[p.type.name].append(p)
        _Gen(rng).block(b, pool, rng.randrange(5, 30), 0)
        # the newest values, so that most of the program is live
        return [pool["f32"][-1], rng.choice(pool["f32"]), pool["i32"][-1], pool["u32"][-1],
                pool["bool"][-1]]

    func(m, "f", PARAMS, RETS, build)
    verify(m)
    return m


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32), data=st.data())
def test_random_programs_are_equivalent(seed, data):
    m = random_module(random.Random(seed))
    text = print_module(m)
    assert print_module(parse_module(text)) == text  # round trip on random programs too
    m2 = optimized(m)
    for _ in range(4):
        args = [data.draw(STRATEGY[t.name]) for t in PARAMS]
        assert_equivalent(m, m2, "f", args)


def kitchen_sink() -> Module:
    """Hand-written function mixing every kind of rewrite with live inputs."""
    def build(b, x, y, k, c):
        one, nz = b.const(1.0, F32), b.const(-0.0, F32)
        a = b.op(Op.ADD, F32, b.op(Op.MUL, F32, x, one), nz)
        m = b.op(Op.MIN, F32, a, y)
        q = b.op(Op.DIV, I32, k, b.op(Op.ADD, I32, b.const(0, I32), k))
        s = b.op(Op.SHR, I32, k, b.const(33, I32))
        nn = b.op(Op.NOT, BOOL, b.op(Op.NOT, BOOL, c))
        sel = b.op(Op.SELECT, F32, nn, m, b.op(Op.ABS, F32, x))
        r = if_(b, b.const(False, BOOL), [F32], lambda tb: [x],
                lambda eb: [eb.op(Op.SUB, F32, sel, b.const(0.0, F32))]).result
        loop = counted_loop(b, 1, r, lambda bb, acc, i: bb.op(
            Op.ADD, F32, acc, bb.op(Op.CAST, F32, i)))
        fk = b.op(Op.CAST, F32, b.op(Op.ADD, I32, q, s))
        return [b.op(Op.ADD, F32, loop, fk), b.op(Op.CAST, I32, loop)]

    return single([F32, F32, I32, BOOL], [F32, I32], build)


@settings(max_examples=300, deadline=None)
@given(x=f32s, y=f32s, k=i32s, c=st.booleans())
def test_kitchen_sink_equivalent(x, y, k, c):
    m = kitchen_sink()
    m2 = optimized(m)
    assert "if" not in body_ops(m2) and "loop" not in body_ops(m2)
    assert_equivalent(m, m2, "f", [x, y, k, c])


def _loops_after_optimize(src: str) -> int:
    from rdsl.compiler.build import Build
    from rdsl.compiler.driver import frontend, pipeline, run_passes

    module = frontend(src)
    run_passes(module, pipeline(Build.of("scalar", "rgb")), stop_after="optimize")
    return sum(i.op is Op.LOOP for f in module.functions.values() for i in f.walk())


def test_a_loop_whose_first_iteration_exits_is_peeled_and_others_are_kept():
    """`peel` replaces a loop whose first iteration is its last by that iteration.  A cheap
    test (`_Maybe`) first rules out loops whose exit cannot fold on the first iteration, so
    the body is not simplified in vain; it must not rule out the loops that do peel: one that
    never runs, one left by `break`, one left by a `break` under an `if`
    on constants."""
    cases = {  # loop: how many loops are left
        "never": ("var i = 5; while i < 1 { x = x * 2.0 + 1.0; i += 1; }", 0),
        "break": ("while true { x = x * 2.0 + 1.0; break; }", 0),
        "if": ("while true { x = x * 2.0; if 3 > 2 { break; } }", 0),
        "data": ("while x < 100.0 { x = x * 2.0 + 1.0; }", 1),
        "count": ("var i = 0; while i < 3 { x = x * 2.0 + 1.0; i += 1; }", 1),
        "break if data": ("while true { x = x * 2.0; if x > 50.0 { break; } }", 1),
    }
    for name, (loop, left) in cases.items():
        src = f"fn f(y: Float) -> Float {{ var x = y; {loop} return x; }}"
        assert _loops_after_optimize(src) == left, name
