"""Typed AST -> SSA IR (:mod:`rdsl.compiler.ir`).

Mutable variables become SSA values tracked in an environment (symbol -> current value).
Structured control flow yields the variables a region changed:

* ``if`` yields the new values of the outer variables either branch assigned;
* ``while c { B }`` is ``loop(vars) { %c = c; %vars' = if %c { B } else {}; yield %c &&
  !broken && !returned, %vars' }`` (do-while loop region, see compiler/ir.py);
* ``for i in a..b`` is the same loop with ``i < b`` and an increment after the body;
* ``break``, ``continue`` and early ``return`` set flag variables; statements that follow a
  statement which may have set a flag are wrapped in ``if !(flags) { ... }``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ..compiler import ir
from ..compiler.builtins import BUILTINS
from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    Block,
    Builder,
    Function,
    Instr,
    Loc,
    MatType,
    Op,
    Param,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    Value,
    VecType,
)
from . import ast as A
from .checker import TEXTURE, CheckedProgram, FnInfo, PluginInfo, Symbol

_ARITH = {"+": Op.ADD, "-": Op.SUB, "*": Op.MUL, "/": Op.DIV, "%": Op.REM}
_BITS = {"&": Op.AND, "|": Op.OR, "^": Op.XOR, "<<": Op.SHL, ">>": Op.SHR}
_CMP = {"==": Op.EQ, "!=": Op.NE, "<": Op.LT, "<=": Op.LE, ">": Op.GT, ">=": Op.GE}


def f32(x: float) -> float:
    """``x`` rounded to the nearest f32, as a python float."""
    return float(np.float32(x))


def ir_type(t: Type) -> Type:
    return ir.SPECTRUM if t is TEXTURE else t


def lower_program(cp: CheckedProgram) -> ir.Module:
    """Lower every function and plugin function of a checked program."""
    mod = ir.Module()
    mod.structs.update(cp.structs)
    for fn in cp.functions:
        mod.add(_FnLowerer(fn).run())
    for pl in cp.plugins:
        for fn in pl.fns.values():
            lowered = mod.add(_FnLowerer(fn, pl).run())
            if fn.name in pl.tables:
                mod.add(_table_read(lowered, pl.tables[fn.name]))
    return mod


TABLE_SLOT = "{}.table"  # the hidden plugin parameter holding a table's offset


def _table_read(fn: Function, options: dict[str, Any]) -> Function:
    """``NAME.read``, what calls to the table function ``NAME`` call: the same parameters
    (and the hidden table offsets), its body the exact function until ``specialize``
    replaces it by the lookup of the scene's table (see compiler/passes/specialize.py)."""
    summed = "sum" in options
    params = [Param(Value(p.value.type, p.value.name), p.uniform, p.default)
              for p in fn.params[1 if summed else 0:]]
    body = ir.Block()
    b = Builder(body, fn.loc)
    if summed:
        b.return_(_sum_loop(b, fn, [p.value for p in params], options["sum"]))
    else:
        call = b.emit(Op.CALL, [p.value for p in params], list(fn.ret_types),
                      {"callee": fn.name})
        b.return_(*call.results)
    method = fn.attrs["method"]
    attrs = {**{k: v for k, v in fn.attrs.items() if k != "export"},
             "table": {"fn": fn.name, "slot": TABLE_SLOT.format(method), **options}}
    return Function(fn.name + ".read", params, list(fn.ret_types), body, fn.loc, attrs)


def _sum_loop(b: Builder, fn: Function, args: list[Value], terms: int) -> Value:
    """The exact value of a `sum` table (before ``specialize`` reads the scene's): the sum
    of ``fn(k, args...)`` over k < ``terms``, in order."""
    k, acc = Value(I32, "k"), Value(F32, "acc")
    blk = ir.Block([k, acc])
    lb = Builder(blk, fn.loc)
    more = lb.op(Op.LT, BOOL, k, lb.const(terms, I32))
    then, other = ir.Block(), ir.Block()
    tb = Builder(then, fn.loc)
    term = tb.emit(Op.CALL, [k, *args], [F32], {"callee": fn.name}).results[0]
    tb.yield_(tb.op(Op.ADD, I32, k, tb.const(1, I32)), tb.op(Op.ADD, F32, acc, term))
    Builder(other, fn.loc).yield_(k, acc)
    step = lb.emit(Op.IF, [more], [I32, F32], regions=[then, other]).results
    lb.yield_(more, *step)
    loop = b.emit(Op.LOOP, [b.const(0, I32), b.const(0.0, F32)], [I32, F32], regions=[blk])
    return loop.results[1]


# --------------------------------------------------------------------------------------
# AST analyses


def _exits(s: A.Stmt) -> set[str]:
    """Which of "return", "break", "continue" ``s`` may perform (for the enclosing loop)."""
    if isinstance(s, A.Return):
        return {"return"}
    if isinstance(s, A.Break):
        return {"break"}
    if isinstance(s, A.Continue):
        return {"continue"}
    if isinstance(s, A.Block):
        return set().union(*(_exits(x) for x in s.stmts)) if s.stmts else set()
    if isinstance(s, (A.If, A.IfConst)):
        out = _exits(s.then)
        if s.else_ is not None:
            out |= _exits(s.else_)
        return out
    if isinstance(s, (A.For, A.While)):
        return _exits(s.body) & {"return"}
    return set()


def _assigned(stmts: list[A.Stmt], out: set[Symbol]) -> set[Symbol]:
    """Symbols assigned (as variables, not buffers) anywhere in ``stmts``."""
    for s in stmts:
        if isinstance(s, A.Assign) and not isinstance(s.target, A.Index):
            root = s.target
            while isinstance(root, (A.Field, A.TupleField)):
                root = root.obj
            if isinstance(root, A.Name) and root.sym is not None:
                out.add(root.sym)
        elif isinstance(s, A.Block):
            _assigned(s.stmts, out)
        elif isinstance(s, (A.If, A.IfConst)):
            _assigned(s.then.stmts, out)
            if s.else_ is not None:
                _assigned([s.else_], out)
        elif isinstance(s, (A.For, A.While)):
            _assigned(s.body.stmts, out)
    return out


def _has_effects(e: Any) -> bool:
    """Whether an expression calls a function or loads memory (no speculation then)."""
    if isinstance(e, A.Call) and (isinstance(e.target, FnInfo) or (
            isinstance(e.target, tuple) and e.target[0] == "builtin"
            and BUILTINS[e.target[1]].effects)):
        return True
    if isinstance(e, A.Index):
        return True
    if isinstance(e, list):
        return any(_has_effects(x) for x in e)
    if isinstance(e, A.FieldInit):
        return _has_effects(e.value)
    if isinstance(e, A.Expr):
        for f in e.__dataclass_fields__:
            v = getattr(e, f)
            if isinstance(v, (A.Expr, list, A.FieldInit)) and _has_effects(v):
                return True
    return False


# --------------------------------------------------------------------------------------
# Function lowering


class _Loop:
    def __init__(self, broken: Symbol | None, continued: Symbol | None) -> None:
        self.broken = broken
        self.continued = continued


class _FnLowerer:
    def __init__(self, fn: FnInfo, plugin: PluginInfo | None = None) -> None:
        self.fn = fn
        self.plugin = plugin
        self.env: dict[Symbol, Value] = {}
        self.body = Block()
        self.b = Builder(self.body, fn.decl.loc)
        self.loops: list[_Loop] = []
        self.returned: Symbol | None = None
        self.retval: Symbol | None = None
        self.plugin_values: list[Value] = []

    # ---- helpers
    def op(self, loc: Loc, op: Op, t: Type, *operands: Value, **attrs: Any) -> Value:
        return self.b.emit(op, list(operands), [t], attrs, loc=loc).result

    def const(self, loc: Loc, value: Any, t: Type) -> Value:
        if t == F32:
            value = f32(value)
        elif t == BOOL:
            value = bool(value)
        elif isinstance(t, ScalarType):
            value = int(value)
        return self.b.emit(Op.CONST, [], [t], {"value": value}, loc=loc).result

    def zero(self, loc: Loc, t: Type) -> Value:
        if isinstance(t, ScalarType):
            return self.const(loc, 0.0 if t == F32 else 0, t)
        if isinstance(t, (VecType, SpectrumType)):
            return self.op(loc, Op.BROADCAST, t, self.const(loc, 0.0, F32))
        if isinstance(t, MatType):
            z = self.const(loc, 0.0, F32)
            return self.op(loc, Op.MAKE, t, *([z] * (t.n * t.n)))
        if isinstance(t, (StructType, TupleType)):
            return self.op(loc, Op.MAKE, t, *(self.zero(loc, c) for c in ir.components(t)))
        raise TypeError(t)  # pragma: no cover

    def plugin_default(self, loc: Loc, t: Type, value: Any) -> Value:
        """A plugin param's default as IR constants (zero when it has none: the scene must
        set it, which ``specialize`` checks)."""
        t = ir_type(t)
        if value is None:
            return self.zero(loc, t)
        if isinstance(t, ScalarType):
            return self.const(loc, value, t)
        if isinstance(value, tuple) and isinstance(t, SpectrumType) and len(value) == 3:
            return self.op(loc, Op.SPEC_RGB, t, *(self.const(loc, v, F32) for v in value))
        if isinstance(value, tuple):
            return self.op(loc, Op.MAKE, t, *(self.const(loc, v, F32) for v in value))
        return self.op(loc, Op.BROADCAST, t, self.const(loc, value, F32))

    def flag(self, name: str) -> Symbol:
        return Symbol(name, BOOL, "var", self.fn.decl.loc)

    # ---- entry
    def run(self) -> Function:
        fn = self.fn
        params: list[Param] = []
        for s in fn.params:
            v = Value(ir_type(s.type), s.name)
            self.env[s] = v
            params.append(Param(v, uniform=isinstance(s.type, ir.BufferType)))
        attrs: dict[str, Any]
        if self.plugin is not None:
            for s, d in zip(self.plugin.params, self.plugin.defaults):
                v = Value(ir_type(s.type), s.name)
                self.env[s] = v
                self.plugin_values.append(v)
                params.append(Param(v, uniform=True, default=d))
            for name in self.plugin.tables:  # where the scene's tables are: see _table_read
                v = Value(ir.I32, TABLE_SLOT.format(name))
                self.plugin_values.append(v)
                params.append(Param(v, uniform=True, default=-1))
            attrs = {"plugin": self.plugin.name, "kind": self.plugin.kind, "method": fn.name}
        else:
            attrs = {"source_name": fn.name}
        if fn.module.is_main:
            attrs = {"export": True, **attrs}
        ret_types = [ir_type(fn.ret)] if fn.ret is not None else []
        loc = fn.decl.loc
        stmts = fn.decl.body.stmts
        nested_return = any("return" in _exits(s) for s in stmts if not isinstance(s, A.Return))
        if nested_return:
            self.returned = self.flag("returned")
            self.env[self.returned] = self.const(loc, False, BOOL)
            if fn.ret is not None:
                self.retval = Symbol("retval", fn.ret, "var", loc)
                self.env[self.retval] = self.zero(loc, ir_type(fn.ret))
        self.stmts(stmts)
        term = self.body.terminator
        if term is None:
            if self.retval is not None:
                self.b.return_(self.env[self.retval]).loc = loc
            else:
                self.b.emit(Op.RETURN, [], [], loc=loc)
        return Function(fn.ir_name, params, ret_types, self.body, loc, attrs)

    # ---- statements
    def stmts(self, stmts: list[A.Stmt]) -> None:
        for i, s in enumerate(stmts):
            self.stmt(s)
            if isinstance(s, (A.Return, A.Break, A.Continue)) or self.body.terminator:
                return  # the rest is dead
            rest = stmts[i + 1:]
            ex = _exits(s)
            if ex and rest:
                flags = self.flags_for(ex)
                loc = rest[0].loc
                acc = self.env[flags[0]]
                for f in flags[1:]:
                    acc = self.op(loc, Op.OR, BOOL, acc, self.env[f])
                go = self.op(loc, Op.NOT, BOOL, acc)
                self.if_(loc, go, lambda: self.stmts(rest), None)  # noqa: B023 (runs now)
                return

    def flags_for(self, ex: set[str]) -> list[Symbol]:
        out: list[Symbol] = []
        if "return" in ex and self.returned is not None:
            out.append(self.returned)
        if self.loops:
            if "break" in ex and self.loops[-1].broken is not None:
                out.append(self.loops[-1].broken)
            if "continue" in ex and self.loops[-1].continued is not None:
                out.append(self.loops[-1].continued)
        assert out, ex
        return out

    def stmt(self, s: A.Stmt) -> None:
        if isinstance(s, A.Block):
            self.stmts(s.stmts)
        elif isinstance(s, A.Let):
            self.bind(s.pattern, self.expr(s.value))
        elif isinstance(s, A.Var):
            v = self.expr(s.value)
            self.name(v, s.name)
            self.env[s.sym] = v
        elif isinstance(s, A.Assign):
            self.assign(s)
        elif isinstance(s, A.If):
            c = self.expr(s.cond)
            self.if_(s.loc, c, lambda: self.stmts(s.then.stmts),
                     (lambda: self.stmt(s.else_)) if s.else_ is not None else None)
        elif isinstance(s, A.IfConst):
            c = self.b.emit(Op.CONST, [], [BOOL], {"trait": s.trait}, loc=s.loc).result
            self.if_(s.loc, c, lambda: self.stmts(s.then.stmts),
                     (lambda: self.stmt(s.else_)) if s.else_ is not None else None)
        elif isinstance(s, A.While):
            self.loop(s.loc, s.body, lambda: self.expr(s.cond), None, None)
        elif isinstance(s, A.For):
            start = self.expr(s.start)
            end = self.expr(s.end)
            self.env[s.sym] = start

            def cond() -> Value:
                return self.op(s.loc, Op.LT, BOOL, self.env[s.sym], end)

            def step() -> None:
                one = self.const(s.loc, 1, I32)
                self.env[s.sym] = self.op(s.loc, Op.ADD, I32, self.env[s.sym], one)

            self.loop(s.loc, s.body, cond, step, s.sym)
        elif isinstance(s, A.Break):
            self.env[self.loops[-1].broken] = self.const(s.loc, True, BOOL)  # type: ignore
        elif isinstance(s, A.Continue):
            self.env[self.loops[-1].continued] = self.const(s.loc, True, BOOL)  # type: ignore
        elif isinstance(s, A.Return):
            v = self.expr(s.value) if s.value is not None else None
            if self.returned is None:
                self.b.emit(Op.RETURN, [v] if v is not None else [], [], loc=s.loc)
            else:
                if v is not None:
                    assert self.retval is not None
                    self.env[self.retval] = v
                self.env[self.returned] = self.const(s.loc, True, BOOL)
        elif isinstance(s, A.ExprStmt):
            self.expr(s.expr)
        else:  # pragma: no cover
            raise TypeError(s)

    def name(self, v: Value, name: str) -> None:
        if v.name is None and isinstance(v.owner, Instr):
            v.name = name

    def bind(self, pat: A.PatName | A.PatTuple, v: Value) -> None:
        if isinstance(pat, A.PatName):
            self.name(v, pat.name)
            self.env[pat.sym] = v
            return
        for i, p in enumerate(pat.elems):
            self.bind(p, self.op(pat.loc, Op.EXTRACT, ir.components(v.type)[i], v, index=i))

    def assign(self, s: A.Assign) -> None:
        t = s.target
        if isinstance(t, A.Index):
            buf = self.expr(t.obj)
            idx = self.expr(t.index)
            val = self.expr(s.value)
            self.b.emit(Op.STORE, [buf, idx, val], [], loc=s.loc)
            return
        val = self.expr(s.value)
        path: list[int] = []
        while isinstance(t, (A.Field, A.TupleField)):
            path.append(t.index)
            t = t.obj
        assert isinstance(t, A.Name)
        path.reverse()
        sym = t.sym
        if path:
            val = self.insert(s.loc, self.env[sym], path, val)
        self.name(val, sym.name)
        self.env[sym] = val

    def insert(self, loc: Loc, agg: Value, path: list[int], val: Value) -> Value:
        idx = path[0]
        if len(path) > 1:
            inner = self.op(loc, Op.EXTRACT, ir.components(agg.type)[idx], agg, index=idx)
            val = self.insert(loc, inner, path[1:], val)
        return self.op(loc, Op.INSERT, agg.type, agg, val, index=idx)

    # ---- structured control flow
    def region(self, fn: Callable[[], None] | None, outer: dict[Symbol, Value]
               ) -> tuple[Block, dict[Symbol, Value]]:
        blk = Block()
        saved = self.b
        self.b = Builder(blk, saved.loc)
        self.env = dict(outer)
        if fn is not None:
            fn()
        env = self.env
        self.b = saved
        return blk, env

    def if_(self, loc: Loc, cond: Value, then: Callable[[], None],
            else_: Callable[[], None] | None) -> None:
        outer = self.env
        tblk, tenv = self.region(then, outer)
        eblk, eenv = self.region(else_, outer)
        changed = [s for s, v in outer.items() if tenv[s] is not v or eenv[s] is not v]
        Builder(tblk).emit(Op.YIELD, [tenv[s] for s in changed], [], loc=loc)
        Builder(eblk).emit(Op.YIELD, [eenv[s] for s in changed], [], loc=loc)
        ins = self.b.emit(Op.IF, [cond], [outer[s].type for s in changed], regions=[tblk, eblk],
                          loc=loc)
        self.env = dict(outer)
        for s, r in zip(changed, ins.results):
            r.name = s.name
            self.env[s] = r

    def loop(self, loc: Loc, body: A.Block, cond: Callable[[], Value],
             step: Callable[[], None] | None, induction: Symbol | None) -> None:
        ex = set().union(*(_exits(x) for x in body.stmts)) if body.stmts else set()
        broken = self.flag("broken") if "break" in ex else None
        continued = self.flag("continued") if "continue" in ex else None
        if broken is not None:
            self.env[broken] = self.const(loc, False, BOOL)
        carried_set = _assigned(body.stmts, set())
        if induction is not None:
            carried_set.add(induction)
        if broken is not None:
            carried_set.add(broken)
        returns = "return" in ex and self.returned is not None
        if returns:
            carried_set.add(self.returned)  # type: ignore[arg-type]
            if self.retval is not None:
                carried_set.add(self.retval)
        outer = self.env
        carried = [s for s in outer if s in carried_set]
        init = [outer[s] for s in carried]
        blk = Block([Value(v.type, s.name) for s, v in zip(carried, init)])
        saved = self.b
        self.b = Builder(blk, loc)
        self.env = dict(outer)
        for s, a in zip(carried, blk.args):
            self.env[s] = a
        self.loops.append(_Loop(broken, continued))
        c = cond()

        def run_body() -> None:
            if continued is not None:
                self.env[continued] = self.const(loc, False, BOOL)
            self.stmts(body.stmts)
            if step is not None:
                step()

        self.if_(loc, c, run_body, None)
        self.loops.pop()
        go = c
        for f in ([broken] if broken is not None else []) + \
                ([self.returned] if returns else []):
            go = self.op(loc, Op.AND, BOOL, go, self.op(loc, Op.NOT, BOOL, self.env[f]))
        for s, v in outer.items():
            assert s in carried_set or self.env[s] is v, f"{s} changed but not carried"
        self.b.emit(Op.YIELD, [go] + [self.env[s] for s in carried], [], loc=loc)
        self.b = saved
        ins = self.b.emit(Op.LOOP, init, [v.type for v in init], regions=[blk], loc=loc)
        self.env = dict(outer)
        for s, r in zip(carried, ins.results):
            r.name = s.name
            self.env[s] = r

    # ---- expressions
    def expr(self, e: A.Expr) -> Value:
        t = ir_type(e.ty) if e.ty is not None else None
        loc = e.loc
        if isinstance(e, A.IntLit):
            return self.const(loc, e.value, t)  # type: ignore[arg-type]
        if isinstance(e, A.FloatLit):
            return self.const(loc, e.value, F32)
        if isinstance(e, A.BoolLit):
            return self.const(loc, e.value, BOOL)
        if isinstance(e, A.Name):
            return self.env[e.sym]
        if isinstance(e, A.Convert):
            v = self.expr(e.expr)
            if isinstance(t, MatType):
                return self.op(loc, Op.MAKE, t, *([v] * (t.n * t.n)))
            return self.op(loc, Op.BROADCAST, t, v)  # type: ignore[arg-type]
        if isinstance(e, A.Unary):
            v = self.expr(e.operand)
            return self.op(loc, Op.NEG if e.op == "-" else Op.NOT, t, v)  # type: ignore
        if isinstance(e, A.Binary):
            return self.binary(e, t)  # type: ignore[arg-type]
        if isinstance(e, A.Call):
            return self.call(e, t)  # type: ignore[return-value]
        if isinstance(e, (A.Field, A.TupleField)):
            v = self.expr(e.obj)
            return self.op(loc, Op.EXTRACT, t, v, index=e.index)  # type: ignore[arg-type]
        if isinstance(e, A.Index):
            buf = self.expr(e.obj)
            idx = self.expr(e.index)
            return self.op(loc, Op.LOAD, t, buf, idx)  # type: ignore[arg-type]
        if isinstance(e, A.TupleExpr):
            vals = [self.expr(x) for x in e.elems]
            return self.op(loc, Op.MAKE, t, *vals)  # type: ignore[arg-type]
        if isinstance(e, A.StructLit):
            vals = [self.expr(fi.value) for fi in e.fields]
            return self.op(loc, Op.MAKE, t, *vals)  # type: ignore[arg-type]
        raise TypeError(e)  # pragma: no cover

    def binary(self, e: A.Binary, t: Type) -> Value:
        loc = e.loc
        if e.op in ("&&", "||"):
            a = self.expr(e.left)
            if not _has_effects(e.right):
                return self.op(loc, Op.AND if e.op == "&&" else Op.OR, BOOL, a,
                               self.expr(e.right))
            # short circuit: only evaluate the right side when it decides the result
            short = e.op == "||"
            rb, _ = self.region(lambda: Builder.emit(self.b, Op.YIELD, [self.expr(e.right)], [],
                                                     loc=loc), self.env)
            cb, _ = self.region(lambda: Builder.emit(self.b, Op.YIELD,
                                                     [self.const(loc, short, BOOL)], [],
                                                     loc=loc), self.env)
            regions = [cb, rb] if short else [rb, cb]
            return self.b.emit(Op.IF, [a], [BOOL], regions=regions, loc=loc).result
        a = self.expr(e.left)
        b = self.expr(e.right)
        if e.op in _ARITH:
            return self.op(loc, _ARITH[e.op], t, a, b)
        if e.op in _BITS:
            return self.op(loc, _BITS[e.op], t, a, b)
        return self.op(loc, _CMP[e.op], BOOL, a, b)

    def call(self, e: A.Call, t: Type | None) -> Value | None:
        loc = e.loc
        target = e.target
        if isinstance(target, FnInfo):
            args = [self.expr(a) for a in e.args]
            attrs: dict[str, Any] = {"callee": target.ir_name}
            if target.plugin is not None and target.plugin is self.plugin:
                args += self.plugin_values
                # a table read, except in a table's own definition (tables are filled
                # independently of each other)
                if target.name in target.plugin.tables and self.fn.decl.table is None:
                    attrs["callee"] += ".read"
            elif target.plugin is not None:  # from outside: `specialize` binds the params
                attrs["bound"] = len(args)
                args += [self.plugin_default(loc, s.type, d)
                         for s, d in zip(target.plugin.params, target.plugin.defaults)]
                # and the tables' offsets (a table function called from outside computes)
                args += [self.const(loc, -1, I32) for _ in target.plugin.tables]
            ins = self.b.emit(Op.CALL, args, [t] if t is not None else [], attrs, loc=loc)
            return ins.results[0] if ins.results else None
        kind, what = target
        if kind == "texture":
            for a in e.args:
                self.expr(a)
            return self.env[what]
        args = [self.expr(a) for a in e.args]
        literals = [a.value if isinstance(a, A.IntLit) else None for a in e.args]
        return BUILTINS[what].emit(Builder(self.b.block, loc), t, args, literals)
