"""``ad_forward``: forward-mode automatic differentiation of scalarized kernels.

Expects: a scalarized module (every value a scalar or a buffer, no calls).  With
``Inline(mark_partials=True)`` each call of a math function of :data:`PARTIALS` left an
``ad.rule`` with its partial derivatives (stdlib/math.rdsl, ``NAME_dK``).

Guarantees: no ``ad.derivative``, ``ad.detach`` or ``ad.rule`` remains.  Without a mode
(``AdForward(None)``, every build without AD) ``derivative(x)`` is 0 and ``detach(x)`` and a
rule are their value.  In ``forward`` mode every ``Float`` value ``v`` gets a tangent ``dv``,
its derivative along a direction given by the seeds:

* a ``load`` from the kernel's parameter buffer ``PRM`` (the generic build's scene
  parameters) has the tangent of the same load from a new buffer argument ``dPRM``;
* a kernel with ``Float`` arguments gets a tangent argument ``d.NAME`` after its own ones
  for each, and a tangent result ``d.NAME`` after its own results for each ``Float``
  result (a Jacobian-vector product: ``abi_params``/``abi_result`` describe both).

``derivative(x)`` is then ``dx``; ``detach(x)`` has tangent 0.  Integers, comparisons,
``floor``/``ceil``, loads from other buffers, ray hits and ``bitcast`` have tangent 0
(derivatives of discontinuities are not taken, as in Mitsuba without reparameterization).
``if`` and ``loop`` carry the tangents of the values they carry.  Zero tangents are
tracked symbolically (None), so code that does not depend on a seed gets no tangent code.
"""

from __future__ import annotations

from ..ir import (
    BOOL,
    F32,
    Block,
    BufferType,
    Builder,
    Function,
    Instr,
    Module,
    Op,
    Param,
    Value,
    clone_block,
    replace_uses,
)
from . import Pass, register

# math function -> the names of its partial derivatives, one per argument (stdlib/math.rdsl)
PARTIALS: dict[str, tuple[str, ...]] = {
    name: tuple(f"{name}_d{k}" for k in range(n)) for name, n in (
        ("sin", 1), ("cos", 1), ("tan", 1), ("exp", 1), ("exp2", 1), ("log", 1), ("log2", 1),
        ("pow", 2), ("atan", 1), ("atan2", 2), ("asin", 1), ("acos", 1), ("erf", 1),
        ("erfinv", 1), ("rsqrt", 1), ("copysign", 2), ("mulsign", 2), ("mulsign_neg", 2))}
PARAM_BUFFER, TANGENT_BUFFER = "PRM", "dPRM"
_LINEAR = {Op.ADD, Op.SUB, Op.NEG}


@register
class AdForward(Pass):
    name = "ad_forward"

    def __init__(self, mode: str | None = None) -> None:
        self.mode = mode

    def run(self, module: Module) -> None:
        for fn in module.functions.values():
            if self.mode is None:
                _strip(fn.body)
            else:
                _Forward(fn).run()


def _strip(block: Block) -> None:
    """Without AD: derivative(x) = 0, detach(x) = x, a rule = its value."""
    mapping: dict[Value, Value] = {}
    _strip_block(block, mapping)
    replace_uses(block, mapping)


def _strip_block(block: Block, mapping: dict[Value, Value]) -> None:
    out = []
    for ins in block.instrs:
        for r in ins.regions:
            _strip_block(r, mapping)
        if ins.op is Op.DETACH:
            mapping[ins.result] = ins.operands[0]
        elif ins.op is Op.AD_RULE:
            mapping[ins.result] = ins.operands[(len(ins.operands) - 1) // 2]
        elif ins.op is Op.DERIV:
            out.append(Instr(Op.CONST, [], [ins.result.type], {"value": 0.0}, loc=ins.loc))
            mapping[ins.result] = out[-1].result
        else:
            out.append(ins)
    block.instrs = out


class _Forward:
    """The tangent program of one function, built alongside its own instructions."""

    def __init__(self, fn: Function) -> None:
        self.fn = fn
        self.tangent: dict[Value, Value] = {}
        self.prm: Value | None = None
        self.dprm: Value | None = None
        # the results of removed instructions (derivative, detach, rule) -> their values
        self.renamed: dict[Value, Value] = {}

    def run(self) -> None:
        fn = self.fn
        for p in fn.params:
            if p.value.name == PARAM_BUFFER and isinstance(p.value.type, BufferType):
                self.prm = p.value
        if self.prm is not None:
            self.dprm = Value(BufferType(F32), TANGENT_BUFFER)
        seeds = [p for p in fn.params if p.value.type == F32]
        new_params = []
        for p in seeds:
            d = Value(F32, f"d.{p.value.name}")
            self.tangent[p.value] = d
            new_params.append(Param(d, p.uniform))
        fn.body = self.block(fn.body, jvp=bool(seeds))
        fn.params += new_params
        if self.dprm is not None:
            fn.params.append(Param(self.dprm, uniform=True))
            entry = next((e for e in fn.attrs.get("abi_params", [])
                          if e["name"] == PARAM_BUFFER), None)
            if entry is not None:
                fn.attrs["abi_params"] = [*fn.attrs["abi_params"], dict(
                    entry, name=TANGENT_BUFFER, leaves=[TANGENT_BUFFER])]
        if seeds:
            self._abi(seeds)

    def _abi(self, seeds: list[Param]) -> None:
        """Record the tangent arguments and results in the kernel's ABI description."""
        fn = self.fn
        extra = [{"name": f"d_{p.value.name}", "type": {"kind": "scalar", "dtype": "f32"},
                  "uniform": p.uniform, "default": None, "leaves": [f"d.{p.value.name}"]}
                 for p in seeds]
        fn.attrs["abi_params"] = [*fn.attrs.get("abi_params", []), *extra]
        floats = [n for n, t in zip(fn.ret_names, fn.ret_types) if t == F32]
        result = fn.attrs.get("abi_result", {})
        tangent_leaves = [f"d.{n}" for n in floats]
        fn.ret_names = [*fn.ret_names, *tangent_leaves]
        fn.ret_types = [*fn.ret_types, *[F32] * len(floats)]
        fn.attrs["abi_result"] = {"type": {"kind": "tuple", "elems": [
            result.get("type"), *[{"kind": "scalar", "dtype": "f32"}] * len(floats)]},
            "leaves": [*result.get("leaves", []), *tangent_leaves], "jvp": True}

    # -- blocks ------------------------------------------------------------------------
    def d(self, v: Value, b: Builder) -> Value:
        """The tangent of ``v`` as a value (a zero constant where it is zero)."""
        t = self.tangent.get(v)
        return t if t is not None else b.const(0.0, F32)

    def block(self, block: Block, jvp: bool = False) -> Block:
        out = Block(block.args)
        b = Builder(out)
        for ins in block.instrs:
            b.loc = ins.loc
            ins.operands = [self.renamed.get(v, v) for v in ins.operands]
            if ins.op is Op.RETURN and jvp:
                floats = [v for v in ins.operands if v.type == F32]
                ins.operands = [*ins.operands, *[self.d(v, b) for v in floats]]
            if ins.op is Op.IF:
                self.if_(ins, b)
            elif ins.op is Op.LOOP:
                self.loop(ins, b)
            else:
                self.instr(ins, b)
        return out

    def if_(self, ins: Instr, b: Builder) -> None:
        ins.regions = [self.block(r) for r in ins.regions]
        k = [i for i, r in enumerate(ins.results) if r.type == F32 and any(
            self.tangent.get(reg.instrs[-1].operands[i]) is not None for reg in ins.regions)]
        for reg in ins.regions:
            self._extend_yield(reg, [reg.instrs[-1].operands[i] for i in k])
        b.block.instrs.append(ins)
        for i in k:
            self.tangent[ins.results[i]] = _new_result(ins)

    def _extend_yield(self, block: Block, values: list[Value]) -> None:
        """Append the tangents of ``values`` to the block's final ``yield``."""
        y = block.instrs.pop()
        tangents = [self.d(v, Builder(block, y.loc)) for v in values]
        y.operands = [*y.operands, *tangents]
        block.instrs.append(y)

    def loop(self, ins: Instr, b: Builder) -> None:
        """Carry the tangents of the Float values the loop carries whose initial value or
        update has one; iterate until that set is stable."""
        body = ins.regions[0]
        carried: set[int] = {i for i, v in enumerate(ins.operands)
                             if v.type == F32 and self.tangent.get(v) is not None}
        saved = dict(self.tangent)
        while True:
            self.tangent = dict(saved)
            args = [Value(F32, f"d.{body.args[i].name or i}") for i in sorted(carried)]
            for i, a in zip(sorted(carried), args):
                self.tangent[body.args[i]] = a
            trial = _copy(body)
            new_body = self.block(trial)
            y = new_body.instrs[-1]
            grown = {i for i, v in enumerate(y.operands[1:]) if v.type == F32 and
                     self.tangent.get(v) is not None} | carried
            if grown == carried:
                break
            carried = grown
        order = sorted(carried)
        self._extend_yield(new_body, [y.operands[1 + i] for i in order])
        for a in args:
            a.owner = new_body
        new_body.args = [*new_body.args, *args]
        ins.regions = [new_body]
        ins.operands = [*ins.operands, *[self.d(ins.operands[i], b) for i in order]]
        b.block.instrs.append(ins)
        for i in order:
            self.tangent[ins.results[i]] = _new_result(ins)

    # -- instructions ------------------------------------------------------------------
    def instr(self, ins: Instr, b: Builder) -> None:
        op = ins.op
        if op is Op.DERIV:
            self.renamed[ins.result] = self.d(ins.operands[0], b)
            return
        if op is Op.DETACH:  # the same value as a new one, which has no tangent
            x = ins.operands[0]
            self.renamed[ins.result] = b.op(Op.SUB, x.type, x, b.const(0.0, x.type))
            return
        if op is Op.AD_RULE:
            n = (len(ins.operands) - 1) // 2
            xs, y, ps = ins.operands[:n], ins.operands[n], ins.operands[n + 1:]
            self.renamed[ins.result] = y
            terms = [_product(b, p, self.tangent[x]) for x, p in zip(xs, ps)
                     if self.tangent.get(x) is not None]
            self._sum(y, terms, b)
            return
        b.block.instrs.append(ins)
        if len(ins.results) != 1 or ins.result.type != F32:
            return
        self.tangent_of(ins, b)

    def _sum(self, v: Value, terms: list[Value], b: Builder) -> None:
        if terms:
            acc = terms[0]
            for t in terms[1:]:
                acc = b.op(Op.ADD, F32, acc, t)
            self.tangent[v] = acc

    # long: one rule per op, as a table would hold them
    def tangent_of(self, ins: Instr, b: Builder) -> None:
        op, ops, y = ins.op, ins.operands, ins.result
        ds = [self.tangent.get(v) for v in ops]
        if op is Op.LOAD and ops[0] is self.prm and self.dprm is not None:
            self.tangent[y] = b.op(Op.LOAD, F32, self.dprm, ops[1])
            return
        if all(d is None for d in ds) or op in (Op.FLOOR, Op.CEIL, Op.CAST, Op.BITCAST,
                                                 Op.CONST, Op.LOAD, Op.REM):
            return
        d = [x if x is not None else b.const(0.0, F32) for x in ds]
        zero = d[0] if ds[0] is None else b.const(0.0, F32)
        if op in _LINEAR:
            self.tangent[y] = b.op(op, F32, *d)
        elif op is Op.MUL:
            self._sum(y, [_product(b, ops[1 - i], t) for i, t in enumerate(ds)
                          if t is not None], b)
        elif op is Op.DIV:  # (da - y db) / b
            num = d[0] if ds[1] is None else b.op(Op.SUB, F32, d[0], _guarded(
                b, ds[1], b.op(Op.MUL, F32, y, ds[1])))
            self.tangent[y] = _guarded(b, num, b.op(Op.DIV, F32, num, ops[1]))
        elif op is Op.SQRT:  # da / (2 y), 0 at y = 0
            q = b.op(Op.DIV, F32, d[0], b.op(Op.ADD, F32, y, y))
            self.tangent[y] = b.op(Op.SELECT, F32, b.op(Op.GT, BOOL, y, zero), q, zero)
        elif op is Op.ABS:
            neg = b.op(Op.LT, BOOL, ops[0], zero)
            self.tangent[y] = b.op(Op.SELECT, F32, neg, b.op(Op.NEG, F32, d[0]), d[0])
        elif op in (Op.MIN, Op.MAX):
            first = b.op(Op.LT if op is Op.MIN else Op.GT, BOOL, ops[0], ops[1])
            self.tangent[y] = b.op(Op.SELECT, F32, first, d[0], d[1])
        elif op is Op.SELECT:
            self.tangent[y] = b.op(Op.SELECT, F32, ops[0], d[1], d[2])


def _guarded(b: Builder, t: Value, p: Value) -> Value:
    """``p`` (a product of the tangent ``t`` and a local partial), 0 where ``t`` is 0: a zero
    tangent carries nothing even through an infinite partial (``sqrt``, a division or a
    rule's partial at a point where it is infinite, as ``c * sqrt(x)`` at x = 0 along c), as
    inf * 0 = NaN would otherwise poison every tangent downstream (ad_reverse's
    ``zero_guard`` is the adjoint's)."""
    zero = b.const(0.0, F32)
    return b.op(Op.SELECT, F32, b.op(Op.EQ, BOOL, t, zero), zero, p)


def _product(b: Builder, p: Value, t: Value) -> Value:
    """The term ``p * t`` of a tangent (a local partial or factor ``p``, a tangent ``t``),
    0 where either is 0: an infinite tangent through a zero factor carries nothing, as the
    adjoint of a product with a zero factor is 0 (``d/dx (c sqrt(x))`` at c = 0, x = 0)."""
    zero = b.const(0.0, F32)
    either = b.op(Op.OR, BOOL, b.op(Op.EQ, BOOL, t, zero), b.op(Op.EQ, BOOL, p, zero))
    return b.op(Op.SELECT, F32, either, zero, b.op(Op.MUL, F32, p, t))


def _new_result(ins: Instr) -> Value:
    """A new Float result appended to ``ins`` (an if or a loop)."""
    v = Value(F32)
    v.owner = ins
    ins.results.append(v)
    return v


def _copy(block: Block) -> Block:
    """A copy of ``block`` to try a loop body on (instructions are rebuilt in place)."""
    copy = clone_block(block, {a: a for a in block.args})
    copy.args = list(block.args)
    return copy
