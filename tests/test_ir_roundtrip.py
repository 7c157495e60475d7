"""print_module / parse_module: exact round trip and the textual form itself."""

from __future__ import annotations

import math

import pytest
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.interp import run_function
from rdsl.compiler.ir import (
    BOOL,
    F32,
    I32,
    U32,
    U64,
    VEC2,
    VEC3,
    Block,
    BufferType,
    Builder,
    Function,
    Loc,
    MatType,
    Module,
    Op,
    Param,
    SpectrumType,
    StructType,
    TupleType,
    Value,
    VecType,
)
from rdsl.compiler.irparse import parse_module
from rdsl.compiler.printer import print_function, print_module
from rdsl.compiler.verify import verify

L = Loc("bsdf.rdsl", 3, 7)


def roundtrip(m: Module, locs: bool = True) -> str:
    text = print_module(m, locs)
    m2 = parse_module(text)
    again = print_module(m2, locs)
    assert again == text
    assert print_module(parse_module(again), locs) == text
    return text


def big_module() -> Module:
    """Structs, nested ifs inside a loop, multi-result ifs, calls, attrs, defaults."""
    inner = StructType("Inner", (("a", F32), ("flag", BOOL)))
    outer = StructType("Outer", (("inner", inner), ("v", VEC3), ("m", MatType(3))))
    m = Module(attrs={"variant": "rgb", "width": 8, "opts": [1, 2.5, None, "x"]})
    m.structs["Outer"] = outer  # deliberately before its dependency
    m.structs["Inner"] = inner

    helper = m.add(Function("helper", [Param(Value(F32, "x"))], [F32], Block(), L))
    hb = Builder(helper.body, L)
    hb.return_(hb.op(Op.MUL, F32, helper.params[0].value, hb.const(0.5, F32)))

    n, alpha, buf = Value(I32, "n"), Value(F32, "alpha"), Value(BufferType(U32), "buf")
    fn = m.add(Function(
        "main", [Param(n), Param(alpha, uniform=True, default=0.1),
                 Param(buf, uniform=True), Param(Value(VEC3, None), default=(1.0, 0.0, -1.5))],
        [F32, outer], Block(), Loc("main.rdsl", 1, 1),
        attrs={"export": True, "kind": "bsdf", "nested": {"k": [True, False]}},
        ret_names=["ret", "s"]))
    b = Builder(fn.body, Loc('we"ird\\name.rdsl', 10, 2))
    v = fn.params[3].value
    zero = b.const(0, I32)
    body = Block([Value(I32, "i"), Value(F32, "acc")])
    bb = Builder(body, L)
    i, acc = body.args
    t, e = Block(), Block()
    tb, eb = Builder(t, L), Builder(e)
    cond = bb.op(Op.LT, BOOL, i, bb.const(4, I32))
    # nested if in the then-branch
    t2, e2 = Block(), Block()
    Builder(t2).yield_(acc, i)
    Builder(e2).yield_(alpha, zero)
    nested = tb.emit(Op.IF, [tb.op(Op.GT, BOOL, acc, alpha)], [F32, I32], regions=[t2, e2])
    tb.yield_(nested.results[0], nested.results[1])
    eb.yield_(eb.emit(Op.CALL, [acc], [F32], {"callee": "helper"}).result, i)
    pair = bb.emit(Op.IF, [cond], [F32, I32], regions=[t, e])
    i1 = bb.op(Op.ADD, I32, pair.results[1], bb.const(1, I32))
    bb.emit(Op.STORE, [buf, i, bb.op(Op.CAST, U32, i1)], [])
    bb.yield_(bb.op(Op.LT, BOOL, i1, n), i1, pair.results[0])
    loop = b.emit(Op.LOOP, [zero, b.const(0.0, F32)], [I32, F32], regions=[body])
    inner_v = b.op(Op.MAKE, inner, loop.results[1], b.const(True, BOOL))
    mat = b.op(Op.BROADCAST, MatType(3), alpha)
    s = b.op(Op.MAKE, outer, inner_v, v, mat)
    b.emit(Op.IF, [b.const(False, BOOL)], [], regions=[Block(), Block()])
    for blk in b.block.instrs[-1].regions:
        Builder(blk).yield_()
    x = b.op(Op.EXTRACT, F32, v, index=2)
    y = b.op(Op.INSERT, VEC3, v, x, index=0)
    b.op(Op.EXTRACT, F32, y, index=0)
    b.emit(Op.CONST, [], [BOOL], {"trait": "polarized"})
    b.op(Op.SPEC_RGB, SpectrumType(), x, x, x)
    b.op(Op.SQRT, F32, x, fast=False, tag="t")
    b.return_(loop.results[1], s)
    return m


def test_big_module_roundtrips_and_verifies():
    m = big_module()
    verify(m)
    text = roundtrip(m)
    roundtrip(m, locs=False)
    verify(parse_module(text))
    assert text.startswith('module attrs {"variant": "rgb", "width": 8, "opts": [1, 2.5, null, "x"]}')
    assert text.index("struct %Inner") < text.index("struct %Outer")
    assert "struct %Outer { inner: %Inner, v: vec3, m: mat3 }" in text
    assert ('func @main(%n: i32, uniform %alpha: f32 = 0.1, uniform %buf: buffer<u32>, '
            '%0: vec3 = [1.0, 0.0, -1.5]) -> (f32, %Outer) ret_names ["ret", "s"] '
            'attrs {"export": true, "kind": "bsdf", "nested": {"k": [true, false]}} '
            'loc("main.rdsl":1:1) {') in text
    assert "%3:2 = loop(%i = %1, %acc = %2) : (i32, f32) loc(" in text
    assert ':2 = if %' in text and "} else {" in text
    assert "call @helper(%acc) : f32" in text
    assert "const trait \"polarized\" : bool" in text
    assert "extract %0 [2] : f32" in text
    assert 'sqrt %' in text and '{"fast": false, "tag": "t"} : f32' in text
    assert 'loc("we\\"ird\\\\name.rdsl":10:2)' in text
    assert "if %" in text and ": () " in text


def test_roundtrip_preserves_semantics():
    m = Module()
    fn = m.add(Function("f", [Param(Value(F32, "x")), Param(Value(I32, "k"))], [F32], Block()))
    b = Builder(fn.body)
    x, k = (p.value for p in fn.params)
    kf = b.op(Op.CAST, F32, k)
    b.return_(b.op(Op.DIV, F32, b.op(Op.ADD, F32, x, kf), b.const(3.0, F32)))
    m2 = parse_module(print_module(m))
    for args in ([1.5, 2], [-0.0, 0], [float("inf"), -7]):
        assert run_function(m, "f", args) == run_function(m2, "f", args)


def test_constants_roundtrip_exactly():
    values = [(0.0, F32), (-0.0, F32), (float("inf"), F32), (float("-inf"), F32),
              (float("nan"), F32), (1e-45, F32), (0.1, F32), (3.4028234663852886e38, F32),
              (1.5e-7, F32), (0, I32), (-(2**31), I32), (2**32 - 1, U32), (2**64 - 1, U64),
              (True, BOOL), (False, BOOL), ((1.0, 2.0), VEC2)]
    neg_nan = -float("nan")
    values.append((neg_nan, F32))
    m = Module()
    fn = m.add(Function("consts", [], [], Block()))
    b = Builder(fn.body)
    for v, t in values:
        b.const(v, t)
    b.return_()
    text = roundtrip(m)
    m2 = parse_module(text)
    got = [ins.attrs["value"] for ins in m2.functions["consts"].body.instrs[:-1]]
    for (want, _), g in zip(values, got):
        assert type(g) in (type(want), list)
        if isinstance(want, float) and math.isnan(want):
            assert math.isnan(g) and math.copysign(1, g) == math.copysign(1, want)
        elif isinstance(want, float):
            assert g == want and math.copysign(1, g) == math.copysign(1, want)
    assert "const -0.0 : f32" in text and "const -inf : f32" in text
    assert "const 18446744073709551615 : u64" in text and "const true : bool" in text


def test_varying_types_roundtrip():
    m = Module()
    w = 8
    f32x, boolx = F32.with_lanes(w), BOOL.with_lanes(w)
    fn = m.add(Function("k", [Param(Value(f32x, "x")), Param(Value(F32, "u"), uniform=True),
                              Param(Value(boolx, "mask"))], [f32x], Block()))
    b = Builder(fn.body)
    x, u, mask = (p.value for p in fn.params)
    ub = b.op(Op.BROADCAST, f32x, u)
    lane = b.op(Op.LANE, I32.with_lanes(w))
    lf = b.op(Op.CAST, f32x, lane)
    s = b.op(Op.SELECT, f32x, mask, b.op(Op.ADD, f32x, x, ub), lf)
    b.op(Op.ANY, BOOL, mask)
    b.op(Op.MAKE, VecType(3, lanes=w), s, s, s)  # a varying aggregate
    b.op(Op.MAKE, TupleType((F32, VecType(2, U32)), lanes=4), u, b.const(0, VecType(2, U32)))
    b.return_(s)
    text = roundtrip(m)
    assert "func @k(%x: f32x8, uniform %u: f32, %mask: boolx8) -> (f32x8) {" in text
    assert "%1 = lane : i32x8" in text
    assert ": varying<8, vec3>" in text and "varying<4, tuple<f32, vec2<u32>>>" in text


def test_param_and_arg_naming():
    m = Module()
    a1, a2 = Value(F32, "a"), Value(F32, "a")  # duplicate names print as numbers
    fn = m.add(Function("f", [Param(a1), Param(a2), Param(Value(F32, "9bad")),
                              Param(Value(F32, "ok.name"))], [F32], Block()))
    b = Builder(fn.body)
    body = Block([Value(F32, "a"), Value(F32, None)])  # "a" clashes with the params
    bb = Builder(body)
    bb.yield_(bb.const(False, BOOL), body.args[1], body.args[0])
    lp = b.emit(Op.LOOP, [a1, a2], [F32, F32], regions=[body])
    b.return_(lp.results[0])
    text = roundtrip(m)
    assert "func @f(%0: f32, %1: f32, %2: f32, %ok.name: f32) -> (f32) {" in text
    assert "%3:2 = loop(%4 = %0, %5 = %1) : (f32, f32) {" in text
    assert "yield %6, %5, %4" in text
    # printing is deterministic and independent of global value ids
    assert print_function(m.functions["f"]) == print_function(m.functions["f"])


def test_empty_module_and_function():
    assert print_module(Module()) == ""
    assert print_module(parse_module("")) == ""
    m = Module()
    fn = m.add(Function("nop", [], [], Block()))
    Builder(fn.body).return_()
    assert roundtrip(m) == "func @nop() -> () {\n  return\n}\n"


def test_comments_and_whitespace_are_ignored():
    text = """
    // a comment
    func @f(%x: f32) -> (f32) {   // trailing
      %0 = add %x, %x : f32
      return %0
    }
    """
    m = parse_module(text)
    assert run_function(m, "f", [1.5])[0] == 3.0


@pytest.mark.parametrize("text,msg,line,col", [
    ("func @f() -> () {\n  %0 = bogus : f32\n  return\n}\n", "unknown op 'bogus'", 2, 8),
    ("func @f() -> () {\n  return %7\n}\n", "use of undefined value %7", 2, 10),
    ("func @f(%x: f33) -> () {\n  return\n}\n", "unknown type 'f33'", 1, 13),
    ("func @f() -> () {\n  %0 = const 1 : i32\n  %0 = const 2 : i32\n  return\n}\n",
     "defined twice", 3, 3),
    ("func @f() -> () {\n  return\n", "expected '}'", 3, 1),
    ("func @f(%s: %Nope) -> () {\n  return\n}\n", "unknown struct %Nope", 1, 13),
    ("func @f() -> () {\n  %0 = const 1 ? i32\n}\n", "unexpected character '?'", 2, 16),
    ("func @f() -> () {\n  %0:2 = add %x : f32\n  return\n}\n", "2 results but 1 types", 2, 10),
])
def test_parse_errors_have_line_and_col(text, msg, line, col):
    with pytest.raises(CompileError) as ei:
        parse_module(text)
    d = ei.value.diagnostics[0]
    assert msg in d.message
    assert (d.loc.line, d.loc.col) == (line, col)
    assert str(ei.value).startswith(f"<ir>:{line}:{col}: error:")
