"""Each verifier error fires, with the function name and the instruction's location."""

from __future__ import annotations

import pytest
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.ir import (
    BOOL,
    F32,
    I32,
    VEC3,
    Block,
    Builder,
    Function,
    Instr,
    Loc,
    Module,
    Op,
    Param,
    Value,
)
from rdsl.compiler.verify import verify

BAD = Loc("bad.rdsl", 7, 9)


def module(build, params=(F32, F32), rets=(F32,)) -> Module:
    """A module with @f; ``build(b, *params)`` emits the body (including the terminator)."""
    m = Module()
    fn = m.add(Function("f", [Param(Value(t, f"p{i}")) for i, t in enumerate(params)],
                        list(rets), Block(), Loc("bad.rdsl", 1, 1)))
    build(Builder(fn.body), *[p.value for p in fn.params])
    return m


def fails(m: Module, msg: str, loc: Loc | None = BAD) -> None:
    with pytest.raises(CompileError) as ei:
        verify(m)
    d = ei.value.diagnostics[0]
    assert msg in d.message, d.message
    assert d.message.startswith("in @f: ")
    if loc is not None:
        assert d.loc == loc


def if_(b: Builder, cond: Value, types, then_vals, else_vals, loc=None) -> Instr:
    t, e = Block(), Block()
    Builder(t, loc or b.loc).yield_(*then_vals)
    Builder(e, loc or b.loc).yield_(*else_vals)
    return b.emit(Op.IF, [cond], list(types), regions=[t, e], loc=loc)


def test_valid_module_passes():
    def build(b, x, y):
        c = b.op(Op.LT, BOOL, x, y)
        r = if_(b, c, [F32], [x], [y]).result
        b.return_(r)
    verify(module(build))


def test_undefined_value():
    stray = Value(F32, "stray")
    fails(module(lambda b, x, y: b.return_(b.emit(Op.ADD, [x, stray], [F32], loc=BAD).result)),
          "operand 1 of 'add' (%1) is used before its definition or outside its scope")


def test_use_before_definition():
    def build(b, x, y):
        later = Instr(Op.NEG, [x], [F32])
        b.emit(Op.ADD, [x, later.result], [F32], loc=BAD)
        b.block.instrs.append(later)
        b.return_(x)
    fails(module(build), "used before its definition")


def test_region_value_not_visible_outside():
    def build(b, x, y):
        t, e = Block(), Block()
        tb = Builder(t)
        inner = tb.op(Op.NEG, F32, x)
        tb.yield_()
        Builder(e).yield_()
        b.emit(Op.IF, [b.op(Op.LT, BOOL, x, y)], [], regions=[t, e])
        b.return_(b.emit(Op.ADD, [x, inner], [F32], loc=BAD).result)
    fails(module(build), "operand 1 of 'add'")


def test_then_value_not_visible_in_else():
    def build(b, x, y):
        t, e = Block(), Block()
        tb = Builder(t)
        inner = tb.op(Op.NEG, F32, x)
        tb.yield_(inner)
        Builder(e, BAD).yield_(inner)
        b.return_(b.emit(Op.IF, [b.op(Op.LT, BOOL, x, y)], [F32], regions=[t, e]).result)
    fails(module(build), "operand 0 of 'yield'")


def test_loop_arg_not_visible_outside():
    def build(b, x, y):
        body = Block([Value(F32, "a")])
        bb = Builder(body)
        bb.yield_(bb.const(False, BOOL), body.args[0])
        b.emit(Op.LOOP, [x], [F32], regions=[body])
        b.return_(b.emit(Op.NEG, [body.args[0]], [F32], loc=BAD).result)
    fails(module(build), "operand 0 of 'neg' (%a)")


def test_missing_terminators():
    fails(module(lambda b, x, y: b.emit(Op.NEG, [x], [F32], loc=BAD)),
          "missing terminator: a function body must end in 'return'")
    fails(module(lambda b, x, y: None), "missing terminator", Loc("bad.rdsl", 1, 1))

    def build(b, x, y):
        t, e = Block(), Block()
        Builder(t, BAD).op(Op.NEG, F32, x)
        Builder(e).yield_()
        b.emit(Op.IF, [b.op(Op.LT, BOOL, x, y)], [], regions=[t, e])
        b.return_(x)
    fails(module(build), "missing terminator: a region must end in 'yield'")


def test_misplaced_terminators():
    def ret_in_region(b, x, y):
        t, e = Block(), Block()
        Builder(t, BAD).return_(x)
        Builder(e).yield_()
        b.emit(Op.IF, [b.op(Op.LT, BOOL, x, y)], [], regions=[t, e])
        b.return_(x)
    fails(module(ret_in_region), "missing terminator: a region must end in 'yield'")

    def ret_then_yield(b, x, y):
        t, e = Block(), Block()
        Builder(t, BAD).return_(x)
        Builder(t).yield_()
        Builder(e).yield_()
        b.emit(Op.IF, [b.op(Op.LT, BOOL, x, y)], [], regions=[t, e])
        b.return_(x)
    fails(module(ret_then_yield), "misplaced terminator 'return' in a region")

    def two_returns(b, x, y):
        b.emit(Op.RETURN, [x], [], loc=BAD)
        b.return_(x)
    fails(module(two_returns), "terminator 'return' is not at the end of its function body")

    def yield_in_body(b, x, y):
        b.emit(Op.YIELD, [], [], loc=BAD)
        b.return_(x)
    fails(module(yield_in_body), "misplaced terminator 'yield' in a function body")


def test_return_types():
    fails(module(lambda b, x, y: b.emit(Op.RETURN, [x, y], [], loc=BAD)),
          "'return' returns (f32, f32) but the function returns (f32)")


def test_if_yield_mismatch():
    def count(b, x, y):
        c = b.op(Op.LT, BOOL, x, y)
        b.return_(if_(b, c, [F32], [x, y], [x], loc=BAD).result)
    fails(module(count), "the 'then' region yields (f32, f32) but the 'if' produces (f32)")

    def types(b, x, y):
        c = b.op(Op.LT, BOOL, x, y)
        b.return_(if_(b, c, [F32], [x], [c], loc=BAD).result)
    fails(module(types), "the 'else' region yields (bool) but the 'if' produces (f32)")


def test_if_condition():
    fails(module(lambda b, x, y: b.return_(if_(b, x, [F32], [x], [y], loc=BAD).result)),
          "if condition must be bool, not f32")

    def varying(b, x, y):
        c = b.op(Op.LT, BOOL.with_lanes(8), x, y)
        b.return_(if_(b, c, [F32], [x], [y], loc=BAD).result)
    fails(module(varying, params=(F32.with_lanes(8),) * 2, rets=(F32,)),
          "if condition is varying (boolx8)")


def loop_module(init_types, arg_types, res_types, yield_fn, cond_type=BOOL) -> Module:
    def build(b, x, y):
        body = Block([Value(t, f"a{i}") for i, t in enumerate(arg_types)])
        bb = Builder(body, BAD)
        c = bb.op(Op.LT, BOOL, x, y) if cond_type == BOOL else bb.op(Op.NEG, cond_type, x)
        yield_fn(bb, c, body.args, x)
        inits = [x if t == F32 else b.const(0, t) for t in init_types]
        lp = b.emit(Op.LOOP, inits, list(res_types), regions=[body], loc=BAD)
        b.return_(x)
        return lp
    return module(build)


def test_loop_checks():
    ok = loop_module([F32], [F32], [F32], lambda bb, c, args, x: bb.yield_(c, *args))
    verify(ok)
    fails(loop_module([F32], [I32], [F32], lambda bb, c, args, x: bb.yield_(c, *args)),
          "loop-carried types differ: operands (f32), body arguments (i32), results (f32)")
    fails(loop_module([F32], [F32], [F32], lambda bb, c, args, x: bb.yield_(c)),
          "a loop body must yield (bool, f32) but yields (bool)")
    fails(loop_module([F32], [F32], [F32], lambda bb, c, args, x: bb.yield_(c, c)),
          "a loop body must yield (bool, f32) but yields (bool, bool)")
    fails(loop_module([F32], [F32], [F32], lambda bb, c, args, x: bb.yield_(c, *args),
                      cond_type=F32),
          "loop continue condition must be bool, not f32")


def test_elementwise_type_mismatch():
    def build(b, x, y):
        i = b.const(1, I32)
        b.return_(b.emit(Op.ADD, [x, i], [F32], loc=BAD).result)
    fails(module(build), "operand types of 'add' differ: f32, i32")

    def result(b, x, y):
        b.return_(b.emit(Op.MUL, [x, y], [VEC3], loc=BAD).result)
    fails(module(result), "'mul' of f32 cannot produce vec3")

    def arity(b, x, y):
        b.return_(b.emit(Op.NEG, [x, y], [F32], loc=BAD).result)
    fails(module(arity), "'neg' takes 1 operands, has 2")


def test_cmp_result_must_be_bool():
    def build(b, x, y):
        b.emit(Op.LT, [x, y], [F32], loc=BAD)
        b.return_(x)
    fails(module(build), "'lt' must produce bool, not f32")

    def mismatch(b, x, y):
        b.emit(Op.EQ, [x, b.const(1, I32)], [BOOL], loc=BAD)
        b.return_(x)
    fails(module(mismatch), "operand types of 'eq' differ")


def test_select_checks():
    def build(b, x, y):
        b.return_(b.emit(Op.SELECT, [x, x, y], [F32], loc=BAD).result)
    fails(module(build), "'select' condition must be bool, not f32")


def test_calls():
    def unknown(b, x, y):
        b.return_(b.emit(Op.CALL, [x], [F32], {"callee": "nowhere"}, loc=BAD).result)
    fails(module(unknown), "call to unknown function @nowhere")

    def self_call_bad_args(b, x, y):
        b.return_(b.emit(Op.CALL, [x], [F32], {"callee": "f"}, loc=BAD).result)
    fails(module(self_call_bad_args), "@f takes (f32, f32) but is called with (f32)")

    def bad_results(b, x, y):
        b.emit(Op.CALL, [x, y], [I32], {"callee": "f"}, loc=BAD)
        b.return_(x)
    fails(module(bad_results), "@f returns (f32) but the call expects (i32)")


def test_error_format_mentions_location():
    m = module(lambda b, x, y: b.return_(b.emit(Op.ADD, [x, b.const(1, I32)], [F32],
                                                loc=BAD).result))
    with pytest.raises(CompileError, match=r"^bad.rdsl:7:9: error: in @f: operand types"):
        verify(m)
