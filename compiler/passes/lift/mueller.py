"""The Mueller (polarized) lowering of one kernel: every ``Spectrum`` becomes a 4x4 Mueller
matrix of unpolarized values, and the shapes of matrices (their known zeros, whether they
are u * identity) are followed through structs, branches and loops."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ....core.color import ColorModel
from ...ir import (
    ARITH_OPS,
    F32,
    Block,
    Builder,
    Instr,
    Op,
    StructType,
    TupleType,
    Type,
    Value,
    clone_block,
    components,
)
from .model import concrete_type, unpolarized_type
from .unpolarized import fail, rewrite_unpolarized

if TYPE_CHECKING:
    from .driver import Lift

_ELEMENTWISE_ONLY = {Op.DIV: "divide", Op.REM: "take the remainder of", Op.SQRT: "`sqrt`",
                     Op.FLOOR: "`floor`", Op.CEIL: "`ceil`", Op.ABS: "`abs`", Op.MIN: "`min`",
                     Op.MAX: "`max`"}


class Mueller:
    """The polarized lowering of one kernel: every ``Spectrum`` is a Mueller matrix of
    unpolarized values (Mitsuba 2, sec. 5: Stokes vectors are its first column).

    Within the kernel it remembers, for each matrix it built, its 16 entries (None where the
    entry is a known zero) and, for u * identity, the unpolarized u.  Products skip known
    zeros, and operations that only make sense elementwise (division, sqrt, min...) are
    allowed on matrices known to be u * identity, where they act on u."""

    def __init__(self, model: ColorModel) -> None:
        self.model = model
        self.base = unpolarized_type(model)
        self.type = concrete_type(model)
        self.entries: dict[Value, list[Value | None]] = {}
        self.scalar: dict[Value, Value] = {}
        self.parts: dict[Value, Any] = {}  # shapes of structs and tuples holding matrices

    def is_mueller(self, v: Value) -> bool:
        return isinstance(v.type, StructType) and v.type.name == "Mueller"

    # -- building blocks -----------------------------------------------------------------
    def zero(self, b: Builder) -> Value:
        z = b.const(0.0, F32)
        return z if self.model.n == 1 else b.op(Op.BROADCAST, self.base, z)

    def get(self, b: Builder, v: Value) -> list[Value | None]:
        if v in self.entries:
            return self.entries[v]
        return [b.op(Op.EXTRACT, self.base, v, index=i) for i in range(16)]

    def entry(self, b: Builder, v: Value, i: int, j: int) -> Value:
        if v in self.scalar:
            return self.scalar[v] if i == j else self.zero(b)
        e = self.get(b, v)[4 * i + j]
        return self.zero(b) if e is None else e

    def make(self, b: Builder, entries: list[Value | None]) -> Value:
        z = self.zero(b) if any(e is None for e in entries) else None
        v = b.op(Op.MAKE, self.type, *[z if e is None else e for e in entries])
        self.entries[v] = entries
        return v

    def from_scalar(self, b: Builder, u: Value) -> Value:
        v = self.make(b, [u if i % 5 == 0 else None for i in range(16)])
        self.scalar[v] = u
        return v

    def splat(self, b: Builder, x: Value) -> Value:
        """An f32 as an unpolarized value."""
        return x if self.model.n == 1 else b.op(Op.BROADCAST, self.base, x)

    def is_zero(self, v: Value) -> bool:
        ins = v.owner
        if isinstance(ins, Instr) and ins.op is Op.BROADCAST:
            ins = ins.operands[0].owner
        return isinstance(ins, Instr) and ins.op is Op.CONST and ins.attrs.get("value") == 0.0 \
            and "trait" not in ins.attrs

    def product(self, b: Builder, x: list[Value | None], y: list[Value | None]) -> list:
        out: list[Value | None] = []
        for i in range(4):
            for j in range(4):
                acc = None
                for k in range(4):
                    p, q = x[4 * i + k], y[4 * k + j]
                    if p is None or q is None:
                        continue
                    t = b.op(Op.MUL, self.base, p, q)
                    acc = t if acc is None else b.op(Op.ADD, self.base, acc, t)
                out.append(acc)
        return out

    # -- what is known across control flow -----------------------------------------------
    # A shape says what is known of a value holding matrices: for a matrix, which entries
    # may be non-zero and whether it is u * identity (``MShape``); for a struct or tuple,
    # the shapes of its fields (None for a field without matrices).
    def full(self, t: Type) -> Any:
        """The shape of a value of type ``t`` of which nothing is known."""
        if isinstance(t, StructType) and t.name == "Mueller":
            return (True,) * 16, False
        if isinstance(t, (StructType, TupleType)):
            parts = tuple(self.full(c) for c in components(t))
            return parts if any(p is not None for p in parts) else None
        return None

    def shape(self, v: Value) -> Any:
        if self.is_mueller(v):
            e = self.entries.get(v)
            nonzero = (True,) * 16 if e is None else tuple(x is not None for x in e)
            return nonzero, v in self.scalar
        return self.parts.get(v) or self.full(v.type)

    def assume(self, b: Builder, v: Value, shape: Any) -> None:
        """Record that ``v`` has ``shape`` (matrix entries are read from ``v`` itself)."""
        if shape is None:
            return
        if not self.is_mueller(v):
            self.parts[v] = shape
            return
        nonzero, scalar = shape
        entries = [b.op(Op.EXTRACT, self.base, v, index=i) if nz else None
                   for i, nz in enumerate(nonzero)]
        self.entries[v] = entries
        if scalar:
            self.scalar[v] = entries[0]

    def join(self, x: Any, y: Any) -> Any:
        if x is None:
            return None
        if len(x) == 2 and isinstance(x[1], bool):  # a matrix
            return tuple(p or q for p, q in zip(x[0], y[0])), x[1] and y[1]
        return tuple(self.join(p, q) for p, q in zip(x, y))

    def track(self, ins: Instr, b: Builder, ops: list[Value]) -> None:
        """Follow shapes into and out of structs and tuples (a BSDF sample's weight)."""
        r = ins.results[0] if len(ins.results) == 1 else None
        if r is None or self.is_mueller(r) and ins.op is not Op.EXTRACT:
            return
        if ins.op is Op.MAKE and self.full(r.type) is not None:
            self.parts[r] = tuple(self.shape(v) if self.full(v.type) is not None else None
                                  for v in ops)
        elif ins.op is Op.INSERT and ops[0] in self.parts:
            parts = list(self.parts[ops[0]])
            parts[ins.attrs["index"]] = self.shape(ops[1])
            self.parts[r] = tuple(parts)
        elif ins.op is Op.EXTRACT and ops[0] in self.parts:
            self.assume(b, r, self.parts[ops[0]][ins.attrs["index"]])

    def merge(self, ins: Instr, mapping: dict[Value, Value]) -> list[Instr]:
        """After an ``if``: a result has the zeros both branches agree on (so a dispatch
        over depolarizing BSDFs still yields a depolarizer)."""
        b = Builder(Block(), ins.loc)
        for k, r in enumerate(ins.results):
            if self.full(r.type) is not None:
                ys = [mapping.get(v, v) for v in (reg.instrs[-1].operands[k]
                                                  for reg in ins.regions)]
                shape = self.shape(ys[0])
                for y in ys[1:]:
                    shape = self.join(shape, self.shape(y))
                self.assume(b, r, shape)
        return b.block.instrs

    def loop(self, lift: Lift, ins: Instr, mapping: dict[Value, Value]) -> list[Instr]:
        """Lift a loop whose carried matrices keep known zeros: assume each starts as its
        initial value's shape, lift the body, and widen the assumption to what the body
        yields until it holds (as Dr.Jit removes constant loop state).  The path tracer's
        throughput thus stays a depolarizer in a scene of depolarizing BSDFs, and the Stokes
        frame rotations around them vanish."""
        original = ins.regions[0]
        inits = [mapping.get(v, v) for v in ins.operands]
        carried = {k: self.shape(v) for k, v in enumerate(inits)
                   if self.full(v.type) is not None}
        if not carried:  # nothing to assume: one pass, in place
            lift.lift_block(original, mapping)
            for r in ins.results:
                r.type = lift.lift_type(r.type)
            return [ins]
        while True:
            body = clone_block(original, {})
            head = Builder(Block(), ins.loc)
            for k, shape in carried.items():
                a = body.args[k]
                a.type = lift.lift_type(a.type)
                self.assume(head, a, shape)
            lift.lift_block(body, mapping)
            body.instrs[:0] = head.block.instrs
            ys = [mapping.get(v, v) for v in body.instrs[-1].operands[1:]]
            wider = {k: self.join(s, self.shape(ys[k])) for k, s in carried.items()}
            if wider == carried:
                break
            carried = wider
        ins.regions[0] = body
        for r in ins.results:
            r.type = lift.lift_type(r.type)
        after = Builder(Block(), ins.loc)
        for k, shape in carried.items():
            self.assume(after, ins.results[k], shape)
        return [ins, *after.block.instrs]

    # -- the ops -------------------------------------------------------------------------
    def rewrite(self, lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
        """Return the replacement of ``ins``'s result, or None to keep it."""
        base = self.base
        res_m = len(ins.results) == 1 and self.is_mueller(ins.result)
        op = ins.op
        if op is Op.BROADCAST and res_m:
            return self.from_scalar(b, self.splat(b, ops[0]))
        if op in (Op.SPEC_RGB, Op.SPEC_TABLE, Op.SPEC_MAKE, Op.SPEC_LAMBDA) and res_m:
            ins.results[0].type = base
            u = rewrite_unpolarized(lift, ins, b, ops)
            ins.results[0].type = self.type
            return self.from_scalar(b, u if u is not None else ins.result)
        if op in (Op.SPEC_AVG, Op.SPEC_MAX, Op.SPEC_SRGB, Op.SPEC_UNPOL):
            x = ops[0]
            if self.is_mueller(x):
                x = self.entry(b, x, 0, 0)
            if op is Op.SPEC_UNPOL:
                return x
            return rewrite_unpolarized(lift, ins, b, [x])
        if op is Op.SPEC_FROM:
            return self.from_scalar(b, ops[0])
        if op is Op.SPEC_DEPOL:
            return self.make(b, [ops[0]] + [None] * 15)
        if op is Op.SPEC_MUELLER:
            return self.make(b, [None if self.is_zero(v) else v for v in ops])
        if op is Op.SPEC_ENTRY:
            return self.entry(b, ops[0], ins.attrs["row"], ins.attrs["col"])
        if not res_m:
            return rewrite_unpolarized(lift, ins, b, ops)
        return self.arith(lift, ins, b, ops)

    def arith(self, lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
        """Arithmetic whose result is a Mueller matrix: the replacement, or None to keep
        ``ins``."""
        base = self.base
        op = ins.op
        if op in ARITH_OPS or op in _ELEMENTWISE_ONLY or op is Op.SELECT:
            mats = [v for v in ops if self.is_mueller(v)]
            if all(v in self.scalar for v in mats):  # all u * identity: act on the u's
                args = [self.scalar.get(v, v) for v in ops]
                picked = (lift.spectral.select(b, ins, args)
                          if op is Op.SELECT and lift.spectral is not None else None)
                if picked is None:
                    picked = b.op(op, base, *args)
                return self.from_scalar(b, picked)
        if op in (Op.ADD, Op.SUB):
            x, y = self.get(b, ops[0]), self.get(b, ops[1])
            out: list[Value | None] = []
            for p, q in zip(x, y):
                if q is None:
                    out.append(p)
                elif p is None:
                    out.append(q if op is Op.ADD else b.op(Op.NEG, base, q))
                else:
                    out.append(b.op(op, base, p, q))
            return self.make(b, out)
        if op is Op.NEG:
            return self.make(b, [None if p is None else b.op(Op.NEG, base, p)
                                 for p in self.get(b, ops[0])])
        if op is Op.SELECT:
            x, y = self.get(b, ops[1]), self.get(b, ops[2])
            out = []
            for p, q in zip(x, y):
                if p is None and q is None:
                    out.append(None)
                else:
                    out.append(b.op(Op.SELECT, base, ops[0], self.zero(b) if p is None else p,
                                    self.zero(b) if q is None else q))
            return self.make(b, out)
        if op is Op.MUL or (op is Op.DIV and ops[1] in self.scalar):
            x, y = ops
            if op is Op.DIV or y in self.scalar or x in self.scalar:
                m, u = (y, self.scalar[x]) if x in self.scalar and op is Op.MUL \
                    else (x, self.scalar[y])
                return self.make(b, [None if p is None else b.op(op, base, p, u)
                                     for p in self.get(b, m)])
            return self.make(b, self.product(b, self.get(b, x), self.get(b, y)))
        if op in _ELEMENTWISE_ONLY:
            what = _ELEMENTWISE_ONLY[op]
            verb = what if not what.startswith("`") else f"apply {what} to"
            raise fail(ins, f"cannot {verb} a polarized Spectrum (a Mueller matrix) in "
                       f"the `{self.model.name}` variant: that is defined on "
                       "unpolarized values only; use `unpolarized(s)` or put this "
                       "code inside `if const polarized { ... } else { ... }`")
        return None

