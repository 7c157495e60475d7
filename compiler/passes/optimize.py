"""``optimize``: constant folding, IEEE-legal simplification, CSE and DCE, to a fixed point.

Expects: a verified module (any stage).  Guarantees: the same observable behaviour, bit for
bit (NaN payloads aside where IEEE allows quieting, e.g. ``x * 1``), checked by differential
tests against the interpreter.  In detail:

* constants are folded with :func:`rdsl.compiler.interp.eval_pure` (the interpreter's own
  semantics), only from ``const`` without a ``trait`` and only to scalar results;
* algebraic rules are the IEEE-exact ones: ``x*1``, ``x/1``, ``x+(-0.0)``, ``x-0.0`` for
  floats (never ``x+0.0`` or ``x*0``), the usual identities for ints and bools,
  ``not not x``, ``neg neg x``, ``select`` with a constant or repeated operand, and
  ``extract`` forwarded through ``make``/``insert``/``broadcast``;
* an ``if`` with a constant condition is replaced by its taken region; a ``loop`` whose
  continue flag is constant false on the first iteration is replaced by one copy of its body;
* a loop-carried value that every iteration passes on unchanged is its initial value (what
  its uses in the body then decide folds in the next run of the pass);
* pure ops are CSE'd within their scope; pure instructions, side-effect-free ``if``/``loop``
  and unused ``if``/``loop`` result slots are deleted;
* functions neither exported (``attrs["export"]``) nor reachable by calls from an exported
  one are removed (only when the module exports something).
"""

from __future__ import annotations

import struct
from collections import deque
from typing import Any

import numpy as np

from ..interp import InterpError, coerce, eval_pure, f32_bits
from ..ir import (
    BOOL,
    PURE_OPS,
    Block,
    Function,
    Instr,
    Module,
    Op,
    ScalarType,
    Value,
    clone_block,
    replace_uses,
)
from . import Pass, register
from .dce import eliminate_dead_code

MAX_ITERATIONS = 50


def _attr_key(v: Any) -> Any:
    """A hashable key that tells apart everything that behaves differently (True vs 1,
    0.0 vs -0.0, NaN payloads)."""
    tv = type(v)  # the common cases first: a float, an int, a one-entry dict
    if tv is float:
        return ("f", struct.pack("<d", v))
    if tv is int:
        return ("i", v)
    if tv is dict:
        return ("d", tuple([(k, _attr_key(v[k])) for k in sorted(v)]))
    if isinstance(v, (bool, np.bool_)):
        return ("b", bool(v))
    if isinstance(v, (int, np.integer)):
        return ("i", int(v))
    if isinstance(v, (float, np.floating)):
        return ("f", struct.pack("<d", float(v)))
    if isinstance(v, (list, tuple)):
        return ("l", tuple(_attr_key(x) for x in v))
    if isinstance(v, dict):
        return ("d", tuple((k, _attr_key(x)) for k, x in sorted(v.items())))
    return ("r", repr(v))


def _to_attr(val: Any, t: ScalarType) -> Any:
    """The ``const`` attribute for an interpreter value, or None if it can't be one exactly."""
    if t.name == "bool":
        return bool(val)
    if t.name == "f32":
        f = float(val)
        return f if f32_bits(coerce(f, t)) == f32_bits(val) else None  # e.g. signalling NaNs
    return int(val)


def _is_scalar(t: Any) -> bool:
    return isinstance(t, ScalarType) and t.lanes == 1


_CMP_EVAL = {Op.EQ: lambda a, b: a == b, Op.NE: lambda a, b: a != b,
             Op.LT: lambda a, b: a < b, Op.LE: lambda a, b: a <= b,
             Op.GT: lambda a, b: a > b, Op.GE: lambda a, b: a >= b}


class _Maybe:
    """Whether a value of a loop's first iteration could simplify to a constant: a cheap
    test before `peel` simplifies a copy of the body.  It answers "no" only when that is
    sure: an input of the iteration that is not a constant (a non-constant initial value, a
    load, a ray query...) reaches the value through operations that keep it non-constant.
    Boolean connectives are followed exactly (false && x is false), an `if` whose condition
    cannot be constant through all its branches; anything else is "maybe"."""

    _OPAQUE = frozenset({Op.LOAD, Op.GATHER, Op.INTERSECT, Op.OCCLUDED, Op.LANE, Op.ANY})
    DEPTH = 64

    def __init__(self, s: _Simplifier, loop: Instr) -> None:
        self.s = s
        self.init = dict(zip(loop.regions[0].args, loop.operands))
        self.inside: dict[Value, Instr] = {}  # a value defined in the loop: its instruction
        inside = self.inside
        stack = [loop.regions[0]]
        while stack:
            for ins in stack.pop().instrs:
                for r in ins.results:
                    inside[r] = ins
                if ins.regions:
                    stack.extend(ins.regions)
        self.memo: dict[tuple[Value, Any], bool] = {}

    def could_be(self, v: Value, want: Any, depth: int = 0) -> bool:
        """Whether ``v`` could simplify to the constant ``want`` (None: to any constant)."""
        if want is None and v.type == BOOL:
            return self.could_be(v, False, depth) or self.could_be(v, True, depth)
        key = (v, want)
        if key not in self.memo:
            self.memo[key] = True  # a cycle (none in SSA) or a deep chain: maybe
            self.memo[key] = depth > self.DEPTH or self._could_be(v, want, depth + 1)
        return self.memo[key]

    def known(self, v: Value) -> Any:
        """The constant ``v`` is in the first iteration, if it is one already."""
        v = self.init.get(v, v)
        if v in self.inside:
            ins = self.inside[v]
            return ins.attrs.get("value") if ins.op is Op.CONST else None
        return self.s.consts.get(self.s.find(v))

    def _could_be(self, v: Value, want: Any, depth: int) -> bool:
        if v in self.init:
            v = self.init[v]
        if v not in self.inside:  # from outside the loop
            c = self.s.consts.get(self.s.find(v))
            return c is not None and (want is None or c == want)
        ins = self.inside[v]
        op = ins.op
        if op is Op.CONST:
            return want is None or "value" not in ins.attrs or ins.attrs["value"] == want
        if op in self._OPAQUE or op is Op.LOOP:
            return op is Op.LOOP
        if op is Op.NOT:
            return self.could_be(ins.operands[0], None if want is None else not want, depth)
        if op in (Op.AND, Op.OR) and ins.result.type == BOOL and want is not None:
            absorbing = op is Op.OR  # true || x, false && x
            if want is absorbing:
                return any(self.could_be(x, want, depth) for x in ins.operands)
            return all(self.could_be(x, want, depth) for x in ins.operands)
        if op is Op.SELECT:
            return any(self.could_be(x, want, depth) for x in ins.operands[1:])
        if op in _CMP_EVAL and all(self.known(x) is not None for x in ins.operands):
            got = _CMP_EVAL[op](*(self.known(x) for x in ins.operands))
            return want is None or bool(got) == want
        if op is Op.IF:
            k = ins.results.index(v)
            ys = [r.instrs[-1].operands[k] for r in ins.regions]
            cond = self.known(ins.operands[0])
            if cond is not None and len(ys) == 2:
                return self.could_be(ys[0 if cond else 1], want, depth)
            if self.could_be(ins.operands[0], None, depth):
                return any(self.could_be(y, want, depth) for y in ys)
            return all(self.could_be(y, want, depth) for y in ys)
        if op in PURE_OPS:
            return all(self.could_be(x, None, depth) for x in ins.operands)
        return True


def _all_known(cs: list[Any]) -> bool:
    """Whether no entry of ``cs`` is None (a loop: ``None in cs`` would compare arrays)."""
    for c in cs:
        if c is None:
            return False
    return True


_NO_ATTRS = _attr_key({})  # most instructions have none: no call, the same key


def _cse_key(ins: Instr) -> tuple[Any, ...]:
    attrs = _attr_key(ins.attrs) if ins.attrs else _NO_ATTRS
    return ins.op, tuple(ins.operands), attrs, ins.results[0].type


class _Simplifier:
    """One forward sweep over a function: folding, rewriting, CSE, region inlining."""

    def __init__(self) -> None:
        self.repl: dict[Value, Value] = {}
        self.consts: dict[Value, Any] = {}
        self.seen: dict[Any, Value] = {}  # CSE table of every enclosing scope
        self.scopes: list[list[Any]] = []  # the keys each open scope added to `seen`
        self.changed = False
        self.again = False  # whether another sweep may find more (see `peel`)
        self.speculating = False

    def find(self, v: Value) -> Value:
        while v in self.repl:
            v = self.repl[v]
        return v

    def block(self, block: Block) -> None:
        self.scopes.append([])
        work = deque(block.instrs)
        out: list[Instr] = []
        repl = self.repl
        while work:
            ins = work.popleft()
            if repl:
                ins.operands = [self.find(v) if v in repl else v for v in ins.operands]
            op = ins.op
            if op in PURE_OPS:
                if len(ins.results) == 1 and not self.pure(ins):
                    continue
            elif op is Op.IF:
                c = self.consts.get(ins.operands[0])
                if c is not None:
                    taken = ins.regions[0 if c else 1]
                    for r, v in zip(ins.results, taken.instrs[-1].operands):
                        self.repl[r] = v
                    work.extendleft(reversed(taken.instrs[:-1]))
                    self.changed = True
                    continue
                for r in ins.regions:
                    self.block(r)
                out.extend(self.same_on_both_sides(ins))
            elif op is Op.LOOP:
                peeled = None if self.speculating else self.peel(ins)
                if peeled is not None:
                    out.extend(peeled)
                    continue
                self.block(ins.regions[0])
                if not self.speculating:
                    self.invariant_slots(ins)
            out.append(ins)
        block.instrs = out
        for key in self.scopes.pop():
            del self.seen[key]

    def peel(self, loop: Instr) -> list[Instr] | None:
        """If the loop's continue flag is a constant false on the first iteration, return the
        (already simplified) instructions of one copy of the body.  Trying means simplifying
        a copy of the body, so `_Maybe` first rules out loops whose flag cannot fold."""
        body = loop.regions[0]
        if not _Maybe(self, loop).could_be(body.instrs[-1].operands[0], False):
            return None
        clone = clone_block(body, dict(zip(body.args, loop.operands)))
        changed = self.changed
        self.speculating = True
        try:
            self.block(clone)
        finally:
            self.speculating = False
        y = clone.instrs[-1]
        if self.consts.get(self.find(y.operands[0])) is not False:
            self.changed = changed
            return None
        for r, v in zip(loop.results, y.operands[1:]):
            self.repl[r] = v
        self.changed = True
        # loops inside were simplified speculatively, so never peeled: leave them to the
        # next sweep (the only thing a sweep leaves for another one)
        self.again = self.again or any(i.op is Op.LOOP for i in clone.walk())
        for ins in clone.instrs[:-1]:  # the copy's values now live in this scope: CSE them
            if ins.op in PURE_OPS and len(ins.results) == 1:
                key = _cse_key(ins)
                if key not in self.seen:
                    self.seen[key] = ins.result
                    self.scopes[-1].append(key)
        return clone.instrs[:-1]

    def invariant_slots(self, loop: Instr) -> None:
        """Carried values that every iteration passes on unchanged (the sampler's kind and
        pixel key through a path tracer's bounces) are their initial values: uses in the body
        and of the result are rewritten to it (DCE then drops the slot), so what depends on
        them folds: in the body in the pipeline's next ``optimize`` (another sweep here, for
        a constant one, cost more compile time than it saved)."""
        body = loop.regions[0]
        y = body.instrs[-1]
        mapping: dict[Value, Value] = {}
        for a, init, nxt, r in zip(body.args, loop.operands, y.operands[1:], loop.results):
            if nxt is a or nxt is init:
                mapping[a] = init
                self.repl[r] = init
        if not mapping:
            return
        replace_uses(body, mapping)
        self.changed = True

    def pure(self, ins: Instr) -> bool:
        """Simplify a pure single-result instruction; False if it was replaced."""
        result = ins.results[0]
        r = self.rewrite(ins)
        if r is not None:
            self.repl[result] = r
            self.changed = True
            return False
        attrs = ins.attrs
        key = (ins.op, tuple(ins.operands), _attr_key(attrs) if attrs else _NO_ATTRS,
               result.type)  # _cse_key
        known = self.seen.get(key)
        if known is not None:
            self.repl[result] = known
            self.changed = True
            return False
        self.seen[key] = result
        self.scopes[-1].append(key)
        if ins.op is Op.CONST and "value" in attrs and "trait" not in attrs:
            try:
                self.consts[result] = coerce(attrs["value"], result.type)
            except (InterpError, TypeError, ValueError, OverflowError):
                pass
        return True

    def same_on_both_sides(self, ins: Instr) -> list[Instr]:
        """Results of ``ins`` (an ``if``) that both branches give alike -- the same outer
        value, or equal scalar constants -- are replaced by that value; returns the constants
        to place before ``ins``.  (A scene whose BSDFs all evaluate to 0 loses its emitter
        sampling this way: its dispatch yields 0 on every side.)"""
        if len(ins.regions) != 2:
            return []
        new: list[Instr] = []
        for k, r in enumerate(ins.results):
            a, b = (self.find(reg.instrs[-1].operands[k]) for reg in ins.regions)
            if a is b:
                self.repl[r] = a
                self.changed = True
                continue
            ca, cb = self.consts.get(a), self.consts.get(b)
            if ca is None or cb is None or not _is_scalar(r.type) \
                    or repr(ca) != repr(cb) or type(ca) is not type(cb):
                continue
            c = Instr(Op.CONST, [], [r.type], dict(a.owner.attrs), loc=ins.loc)
            self.consts[c.result] = ca
            self.repl[r] = c.result
            self.changed = True
            new.append(c)
        return new

    def make_const(self, ins: Instr, val: Any) -> bool:
        attr = _to_attr(val, ins.result.type)
        if attr is None:
            return False
        ins.op, ins.operands, ins.attrs = Op.CONST, [], {"value": attr}
        self.changed = True
        return True

    def rewrite(self, ins: Instr) -> Value | None:
        """Return a value equal to ``ins``'s result, or None (possibly after rewriting
        ``ins`` in place, e.g. into a constant)."""
        op = ins.op
        if op is Op.CONST:
            return None
        ops, t = ins.operands, ins.results[0].type
        consts = self.consts
        cs = [consts.get(v) for v in ops]
        scalar = isinstance(t, ScalarType) and t.lanes == 1  # _is_scalar(t)
        if scalar and ops and _all_known(cs) and all(v.type.lanes == 1 for v in ops):
            try:
                val = eval_pure(op, t, [v.type for v in ops], cs, ins.attrs)
            except (InterpError, IndexError, KeyError, TypeError):
                val = None
            if val is not None and self.make_const(ins, val):
                return None
        if op in _ALGEBRA:  # the common case first: arithmetic and comparisons
            if not scalar or not ops or ops[0].type != t and op not in _CMP:
                return None
            return _ALGEBRA[op](self, ins, ops, cs, t)
        if op is Op.SELECT:
            if cs[0] is not None:
                return ops[1] if cs[0] else ops[2]
            if ops[1] is ops[2]:
                return ops[1]
            if t == ops[0].type and cs[1] is True and cs[2] is False:
                return ops[0]
            return None
        if op in (Op.CAST, Op.BITCAST):
            return ops[0] if ops[0].type == t else None
        if op is Op.EXTRACT:
            return self.extract(ins)
        return None

    def extract(self, ins: Instr) -> Value | None:
        idx = ins.attrs.get("index")
        while True:
            src = ins.operands[0]
            d = src.owner
            if not isinstance(d, Instr):
                return None
            if d.op is Op.MAKE and isinstance(idx, int) and idx < len(d.operands):
                v = d.operands[idx]
                return v if v.type == ins.result.type else None
            if d.op is Op.BROADCAST and d.operands[0].type == ins.result.type:
                return d.operands[0]
            if d.op is Op.INSERT:
                if d.attrs.get("index") == idx:
                    return d.operands[1] if d.operands[1].type == ins.result.type else None
                ins.operands = [d.operands[0]]
                self.changed = True
                continue
            return None


# --------------------------------------------------------------------------------------
# Algebraic identities (scalars only; every rule is exact under IEEE-754 and wrapping ints)

_CMP = {Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE}


def _is(c: Any, t: ScalarType, x: float) -> bool:
    """Is constant ``c`` exactly ``x`` (for floats: the same bits, so -0.0 != 0.0)?"""
    if c is None:
        return False
    if t.name == "f32":
        return f32_bits(c) == f32_bits(np.float32(x))
    if t.name == "bool":
        return bool(c) == bool(x)
    return int(c) == x


def _ones(t: ScalarType) -> int:
    return {"i32": -1, "u32": 0xFFFF_FFFF, "u64": 0xFFFF_FFFF_FFFF_FFFF, "bool": 1}[t.name]


def _zero(s: _Simplifier, ins: Instr, t: ScalarType) -> None:
    s.make_const(ins, coerce(0, t))


def _add(s, ins, ops, cs, t):
    zero = -0.0 if t.is_float else 0  # x + (-0.0) == x for every x; x + 0.0 is not
    if _is(cs[1], t, zero):
        return ops[0]
    if _is(cs[0], t, zero):
        return ops[1]
    return None


def _sub(s, ins, ops, cs, t):
    if _is(cs[1], t, 0):  # x - (+0.0) == x
        return ops[0]
    if t.is_int and ops[0] is ops[1]:
        _zero(s, ins, t)
    return None


def _mul(s, ins, ops, cs, t):
    if _is(cs[1], t, 1):
        return ops[0]
    if _is(cs[0], t, 1):
        return ops[1]
    if t.is_int and (_is(cs[0], t, 0) or _is(cs[1], t, 0)):
        _zero(s, ins, t)
    return None


def _div(s, ins, ops, cs, t):
    return ops[0] if _is(cs[1], t, 1) else None


def _rem(s, ins, ops, cs, t):
    if t.is_int and _is(cs[1], t, 1):
        _zero(s, ins, t)


def _and(s, ins, ops, cs, t):
    if ops[0] is ops[1]:
        return ops[0]
    for a, c in ((ops[0], cs[1]), (ops[1], cs[0])):
        if _is(c, t, _ones(t)):
            return a
        if _is(c, t, 0):
            _zero(s, ins, t)
            return None
    return None


def _or(s, ins, ops, cs, t):
    if ops[0] is ops[1]:
        return ops[0]
    for a, c in ((ops[0], cs[1]), (ops[1], cs[0])):
        if _is(c, t, 0):
            return a
        if _is(c, t, _ones(t)):
            s.make_const(ins, coerce(_ones(t), t))
            return None
    return None


def _xor(s, ins, ops, cs, t):
    if _is(cs[1], t, 0):
        return ops[0]
    if _is(cs[0], t, 0):
        return ops[1]
    if ops[0] is ops[1]:
        _zero(s, ins, t)
    return None


def _involution(s, ins, ops, cs, t):
    d = ops[0].owner  # not(not x) == x, neg(neg x) == x (sign-bit flips for floats)
    if isinstance(d, Instr) and d.op is ins.op and d.operands[0].type == t:
        return d.operands[0]
    return None


def _shift(s, ins, ops, cs, t):
    return ops[0] if cs[1] is not None and int(cs[1]) % t.bits == 0 else None


def _minmax(s, ins, ops, cs, t):
    return ops[0] if ops[0] is ops[1] else None


def _cmp(s, ins, ops, cs, t):
    a = ops[0].type
    if ops[0] is ops[1] and isinstance(a, ScalarType) and not a.is_float and a.lanes == 1:
        s.make_const(ins, ins.op in (Op.EQ, Op.LE, Op.GE))


_ALGEBRA = {
    Op.ADD: _add, Op.SUB: _sub, Op.MUL: _mul, Op.DIV: _div, Op.REM: _rem,
    Op.AND: _and, Op.OR: _or, Op.XOR: _xor, Op.NOT: _involution, Op.NEG: _involution,
    Op.SHL: _shift, Op.SHR: _shift, Op.MIN: _minmax, Op.MAX: _minmax,
    **{op: _cmp for op in _CMP},
}

def _remove_dead_functions(m: Module) -> None:
    roots = [f for f in m.functions.values() if f.attrs.get("export")]
    if not roots:
        return
    reached: set[str] = set()
    stack = [f.name for f in roots]
    while stack:
        name = stack.pop()
        if name in reached or name not in m.functions:
            continue
        reached.add(name)
        stack.extend(i.attrs.get("callee") for i in m.functions[name].walk() if i.op is Op.CALL)
    m.functions = {n: f for n, f in m.functions.items() if n in reached}


def optimize_function(fn: Function) -> None:
    """Simplify ``fn`` in place to a fixed point: one sweep and DCE, and another only where
    a sweep says it left something (a loop inside a peeled loop), up to MAX_ITERATIONS.  A
    sweep goes forward and sees every simplification before it, so a confirming sweep found
    nothing on any of 1370 stdlib and scene kernels and cost 43% of this pass;
    tests/test_optimize.py checks that the result is a fixed point."""
    with np.errstate(all="ignore"):
        for _ in range(MAX_ITERATIONS):
            s = _Simplifier()
            s.block(fn.body)
            changed = eliminate_dead_code(fn) or s.changed
            if not (changed and s.again):
                return


@register
class Optimize(Pass):
    """Constant folding, IEEE-exact simplification, CSE, DCE and dead-function removal."""

    name = "optimize"

    def run(self, module: Module) -> Module:
        for fn in module.functions.values():
            optimize_function(fn)
        _remove_dead_functions(module)
        return module
