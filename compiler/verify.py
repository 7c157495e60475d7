"""The IR verifier: structural and type invariants every pass must preserve.

``verify(module)`` raises :class:`CompileError` at the offending instruction's location,
naming the function, on the first problem found: values used before (or outside the scope
of) their definition, misplaced or missing terminators, ``if``/``loop``/``return``/``call``
signature mismatches, bad conditions (not ``bool``, or varying) and operand type mismatches.
"""

from __future__ import annotations

from .diagnostics import CompileError
from .ir import (
    BOOL,
    CMP_OPS,
    Block,
    BufferType,
    Function,
    Instr,
    Loc,
    Module,
    Op,
    ScalarType,
    Type,
    Value,
)
from .printer import Namer, type_str, types_str

_BINARY = {Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.REM, Op.AND, Op.OR, Op.XOR, Op.SHL, Op.SHR,
           Op.MIN, Op.MAX}
_UNARY = {Op.NEG, Op.NOT, Op.SQRT, Op.FLOOR, Op.CEIL, Op.ABS, Op.DERIV, Op.DETACH}


def _tl(ts: list[Type]) -> str:
    return types_str(ts)


class _FnVerifier:
    def __init__(self, module: Module, fn: Function) -> None:
        self.module = module
        self.fn = fn
        self.name = Namer(fn)
        self.scopes: list[set[Value]] = []

    def fail(self, msg: str, loc: Loc | None) -> CompileError:
        return CompileError(f"in @{self.fn.name}: {msg}", loc or self.fn.loc)

    def run(self) -> None:
        fn = self.fn
        self.scopes.append({p.value for p in fn.params})
        self.block(fn.body, Op.RETURN, fn.loc)
        term = fn.body.instrs[-1]
        got = [v.type for v in term.operands]
        if got != fn.ret_types:
            raise self.fail(f"'return' returns {_tl(got)} but the function returns "
                            f"{_tl(fn.ret_types)}", term.loc)

    def block(self, block: Block, terminator: Op, loc: Loc) -> None:
        """Check a region (pushing a scope for its arguments and results)."""
        where = "function body" if terminator is Op.RETURN else "region"
        if not block.instrs or block.instrs[-1].op is not terminator:
            last = block.instrs[-1].loc if block.instrs else loc
            raise self.fail(f"missing terminator: a {where} must end in '{terminator.value}'",
                            last)
        self.scopes.append(set(block.args))
        for i, ins in enumerate(block.instrs):
            if ins.op in (Op.YIELD, Op.RETURN):
                if ins.op is not terminator:
                    raise self.fail(f"misplaced terminator '{ins.op.value}' in a {where}",
                                    ins.loc)
                if i != len(block.instrs) - 1:
                    raise self.fail(f"terminator '{ins.op.value}' is not at the end of its "
                                    f"{where}", ins.loc)
            self.instr(ins)
            self.scopes[-1].update(ins.results)
        self.scopes.pop()

    def visible(self, v: Value) -> bool:
        return any(v in s for s in self.scopes)

    def instr(self, ins: Instr) -> None:
        op = ins.op
        for i, v in enumerate(ins.operands):
            if not isinstance(v, Value) or not self.visible(v):
                raise self.fail(f"operand {i} of '{op.value}' ({self.name(v)}) is used before "
                                "its definition or outside its scope", ins.loc)
        ots = [v.type for v in ins.operands]
        rts = [r.type for r in ins.results]
        if op is Op.IF:
            self.if_instr(ins, rts)
        elif op is Op.LOOP:
            self.loop_instr(ins, ots, rts)
        elif ins.regions:
            raise self.fail(f"'{op.value}' cannot have regions", ins.loc)
        else:
            self.simple_instr(ins, ots, rts)

    def if_instr(self, ins: Instr, rts: list[Type]) -> None:
        """An ``if``: a bool condition, then/else regions yielding its result types."""
        self.expect_counts(ins, 1, None)
        self.condition(ins, ins.operands[0], "if")
        if len(ins.regions) != 2:
            raise self.fail(f"'if' needs 2 regions, has {len(ins.regions)}", ins.loc)
        for name, r in zip(("then", "else"), ins.regions):
            if r.args:
                raise self.fail(f"the '{name}' region of an 'if' takes no arguments",
                                ins.loc)
            self.block(r, Op.YIELD, ins.loc)
            y = r.instrs[-1]
            got = [v.type for v in y.operands]
            if got != rts:
                raise self.fail(f"the '{name}' region yields {_tl(got)} but the 'if' "
                                f"produces {_tl(rts)}", y.loc)

    def loop_instr(self, ins: Instr, ots: list[Type], rts: list[Type]) -> None:
        """A ``loop``: carried values typed alike as operands, body arguments and results."""
        if len(ins.regions) != 1:
            raise self.fail(f"'loop' needs 1 region, has {len(ins.regions)}", ins.loc)
        body = ins.regions[0]
        argts = [a.type for a in body.args]
        if not (ots == argts == rts):
            raise self.fail(f"loop-carried types differ: operands {_tl(ots)}, body "
                            f"arguments {_tl(argts)}, results {_tl(rts)}", ins.loc)
        self.block(body, Op.YIELD, ins.loc)
        y = body.instrs[-1]
        got = [v.type for v in y.operands]
        if not y.operands or got[1:] != rts:
            raise self.fail(f"a loop body must yield {_tl([BOOL, *rts])} but yields "
                            f"{_tl(got)}", y.loc)
        self.condition(y, y.operands[0], "loop continue")

    def simple_instr(self, ins: Instr, ots: list[Type], rts: list[Type]) -> None:
        """An instruction without regions: operand and result types by op category."""
        op = ins.op
        if op in _BINARY or op in _UNARY:
            self.expect_counts(ins, 2 if op in _BINARY else 1, 1)
            if len(set(ots)) != 1:
                raise self.fail(f"operand types of '{op.value}' differ: "
                                f"{', '.join(type_str(t) for t in ots)}", ins.loc)
            if rts[0] != ots[0]:
                raise self.fail(f"'{op.value}' of {type_str(ots[0])} cannot produce "
                                f"{type_str(rts[0])}", ins.loc)
        elif op in CMP_OPS:
            self.expect_counts(ins, 2, 1)
            if ots[0] != ots[1]:
                raise self.fail(f"operand types of '{op.value}' differ: {type_str(ots[0])}, "
                                f"{type_str(ots[1])}", ins.loc)
            r = rts[0]
            if not (isinstance(r, ScalarType) and r.name == "bool" and r.lanes == ots[0].lanes):
                raise self.fail(f"'{op.value}' must produce {type_str(BOOL.with_lanes(ots[0].lanes))},"
                                f" not {type_str(r)}", ins.loc)
        elif op is Op.SELECT:
            self.expect_counts(ins, 3, 1)
            c = ots[0]
            if not (isinstance(c, ScalarType) and c.name == "bool"):
                raise self.fail(f"'select' condition must be bool, not {type_str(c)}", ins.loc)
            if not (ots[1] == ots[2] == rts[0]):
                raise self.fail(f"'select' operand and result types differ: {type_str(ots[1])},"
                                f" {type_str(ots[2])} -> {type_str(rts[0])}", ins.loc)
        elif op is Op.CONST:
            self.expect_counts(ins, 0, 1)
        elif op is Op.CALL:
            callee = self.module.functions.get(ins.attrs.get("callee"))
            if callee is None:
                raise self.fail(f"call to unknown function @{ins.attrs.get('callee')}", ins.loc)
            pts = [p.value.type for p in callee.params]
            if ots != pts:
                raise self.fail(f"@{callee.name} takes {_tl(pts)} but is called with "
                                f"{_tl(ots)}", ins.loc)
            if rts != callee.ret_types:
                raise self.fail(f"@{callee.name} returns {_tl(callee.ret_types)} but the call "
                                f"expects {_tl(rts)}", ins.loc)
        elif op in (Op.LOAD, Op.STORE, Op.GATHER, Op.SCATTER):
            if not ots or not isinstance(ots[0], BufferType):
                raise self.fail(f"'{op.value}' needs a buffer as its first operand", ins.loc)
        elif op in (Op.EXTRACT, Op.INSERT) and not isinstance(ins.attrs.get("index"), int):
            raise self.fail(f"'{op.value}' needs an integer 'index' attribute", ins.loc)

    def expect_counts(self, ins: Instr, n_operands: int, n_results: int | None) -> None:
        if len(ins.operands) != n_operands:
            raise self.fail(f"'{ins.op.value}' takes {n_operands} operands, has "
                            f"{len(ins.operands)}", ins.loc)
        if n_results is not None and len(ins.results) != n_results:
            raise self.fail(f"'{ins.op.value}' has {n_results} result(s), not "
                            f"{len(ins.results)}", ins.loc)

    def condition(self, ins: Instr, v: Value, what: str) -> None:
        t = v.type
        if not (isinstance(t, ScalarType) and t.name == "bool"):
            raise self.fail(f"{what} condition must be bool, not {type_str(t)}", ins.loc)
        if t.lanes != 1:
            raise self.fail(f"{what} condition is varying ({type_str(t)}); control flow must "
                            "be uniform", ins.loc)


def verify(m: Module) -> None:
    """Check every function of ``m``; raise :class:`CompileError` on the first problem."""
    for fn in m.functions.values():
        _FnVerifier(m, fn).run()


__all__ = ["verify"]
