"""``vectorize(width)``: SPMD over ``width`` lanes, with masks.

Expects: a scalarized module (scalars and buffers only, no calls).

Guarantees, for every exported function:
- a last parameter ``mask`` (``bool`` x width) is the execution mask;
- values that depend on a mapped parameter are *varying* (``lanes == width``); everything
  else stays *uniform* (``lanes == 1``) and scalar;
- every ``if`` and ``loop`` condition is uniform:
  - a varying ``if`` becomes ``if any(mask & c) { then }`` and ``if any(mask & !c)
    { else }`` followed by a ``select``, so a side with no active lane is skipped, and a
    side that computes nothing costs nothing;
  - a loop with a varying continue flag carries an ``active`` mask and runs while
    ``any(active)``; lanes that finished keep their values;
- ``load``/``store`` with a varying index or under a partial mask become ``gather``/
  ``scatter`` with the current mask.

With width 1 the body is wrapped in ``if mask { ... }`` and control flow is unchanged.
"""

from __future__ import annotations

from ..ir import (
    BOOL,
    Block,
    BufferType,
    Builder,
    Function,
    Instr,
    Module,
    Op,
    Param,
    ScalarType,
    Type,
    Value,
)
from . import Pass, register


@register
class Vectorize(Pass):
    name = "vectorize"

    def __init__(self, width: int = 8) -> None:
        self.width = width

    def run(self, module: Module) -> None:
        module.attrs["width"] = self.width
        for fn in module.functions.values():
            if self.width == 1:
                _wrap_scalar(fn)
            else:
                _FunctionVectorizer(fn, self.width).run()


def _zero(b: Builder, t: Type) -> Value:
    assert isinstance(t, ScalarType)
    value = {"f32": 0.0, "bool": False}.get(t.name, 0)
    v = b.const(value, t.with_lanes(1))
    return b.op(Op.BROADCAST, t, v) if t.lanes > 1 else v


def _wrap_scalar(fn: Function) -> None:
    """Width 1: run the body only when the (single) lane is active."""
    mask = Value(BOOL, "mask")
    body = fn.body
    ret = body.instrs.pop()
    body.instrs.append(Instr(Op.YIELD, ret.operands, [], loc=ret.loc))
    other = Block()
    ob = Builder(other, ret.loc)
    ob.yield_(*[_zero(ob, t) for t in fn.ret_types])
    new = Block()
    nb = Builder(new, fn.loc)
    res = nb.emit(Op.IF, [mask], list(fn.ret_types), regions=[body, other])
    nb.return_(*res.results)
    fn.body = new
    fn.params.append(Param(mask, False))


# Regions at most this long, with only pure ops, are if-converted without a branch.
CHEAP_REGION = 12
_UNSAFE = {Op.IF, Op.LOOP, Op.LOAD, Op.STORE, Op.GATHER, Op.SCATTER, Op.CALL, Op.INTERSECT,
           Op.OCCLUDED}


def _is_cheap(region: Block) -> bool:
    body = region.instrs[:-1]
    return len(body) <= CHEAP_REGION and not any(i.op in _UNSAFE for i in body)


class _FunctionVectorizer:
    def __init__(self, fn: Function, width: int) -> None:
        self.fn = fn
        self.W = width
        self.varying: set[Value] = set()
        self.env: dict[Value, Value] = {}

    # -- uniformity analysis -------------------------------------------------------------
    def _analyze(self) -> None:
        for p in self.fn.params:
            if not p.uniform:
                self.varying.add(p.value)
        changed = True
        while changed:
            changed = self._analyze_block(self.fn.body)

    def _analyze_block(self, block: Block) -> bool:
        changed = False
        for ins in block.instrs:
            if ins.op is Op.IF:
                div = ins.operands[0] in self.varying
                for r in ins.regions:
                    changed |= self._analyze_block(r)
                for i, res in enumerate(ins.results):
                    if div or any(r.instrs[-1].operands[i] in self.varying
                                  for r in ins.regions):
                        changed |= self._mark(res)
            elif ins.op is Op.LOOP:
                body = ins.regions[0]
                y = body.instrs[-1]
                div = y.operands[0] in self.varying
                for i, (arg, res) in enumerate(zip(body.args, ins.results)):
                    if div or ins.operands[i] in self.varying \
                            or y.operands[i + 1] in self.varying:
                        changed |= self._mark(arg)
                        changed |= self._mark(res)
                changed |= self._analyze_block(body)
            elif ins.results and ins.op is not Op.ANY and (
                    ins.op in (Op.INTERSECT, Op.OCCLUDED)
                    or any(v in self.varying for v in ins.operands)):
                for r in ins.results:
                    changed |= self._mark(r)
        return changed

    def _mark(self, v: Value) -> bool:
        if v in self.varying:
            return False
        self.varying.add(v)
        return True

    # -- transformation --------------------------------------------------------------------
    def run(self) -> None:
        fn, W = self.fn, self.W
        self._analyze()
        params = []
        for p in fn.params:
            v = p.value
            nv = Value(v.type.with_lanes(W) if v in self.varying else v.type, v.name)
            self.env[v] = nv
            params.append(Param(nv, p.uniform, p.default))
        mask = Value(BOOL.with_lanes(W), "mask")
        params.append(Param(mask, False))
        ret = fn.body.instrs[-1]
        fn.ret_types = [t.with_lanes(W) if v in self.varying else t
                        for t, v in zip(fn.ret_types, ret.operands)]
        body = self._block(fn.body, mask, [], partial=True)
        Builder(body, ret.loc).return_(*self._terminate(fn.body, body, fn.ret_types))
        fn.body = body
        fn.params = params

    def vtype(self, v: Value) -> Type:
        return v.type.with_lanes(self.W) if v in self.varying else v.type

    def _get(self, b: Builder, v: Value, varying: bool) -> Value:
        """The new value for old ``v``, broadcast if a varying value is needed."""
        nv = self.env[v]
        if varying and nv.type.lanes == 1 and not isinstance(nv.type, BufferType):
            return b.op(Op.BROADCAST, nv.type.with_lanes(self.W), nv)
        return nv

    def _block(self, block: Block, mask: Value, args: list[Value], partial: bool) -> Block:
        out = Block(args)
        b = Builder(out)
        for ins in block.instrs[:-1]:  # the terminator is emitted by the caller
            b.loc = ins.loc
            self._instr(ins, b, mask, partial)
        return out

    def _instr(self, ins: Instr, b: Builder, mask: Value, partial: bool) -> None:
        op = ins.op
        if op is Op.IF:
            if ins.operands[0] in self.varying:
                self._varying_if(ins, b, mask)
            else:
                self._uniform_if(ins, b, mask, partial)
            return
        if op is Op.LOOP:
            self._loop(ins, b, mask, partial)
            return
        if op in (Op.YIELD, Op.RETURN):
            raise AssertionError("terminators are handled by their region")
        if op is Op.LOAD and (ins.operands[1] in self.varying):
            buf = self.env[ins.operands[0]]
            idx = self._get(b, ins.operands[1], True)
            r = b.emit(Op.GATHER, [buf, idx, mask], [self.vtype(ins.result)]).result
            self.env[ins.result] = r
            return
        if op is Op.STORE and (partial or any(v in self.varying for v in ins.operands[1:])):
            buf = self.env[ins.operands[0]]
            idx = self._get(b, ins.operands[1], True)
            val = self._get(b, ins.operands[2], True)
            b.emit(Op.SCATTER, [buf, idx, val, mask], [])
            return
        if op in (Op.INTERSECT, Op.OCCLUDED):  # ray queries take the execution mask
            ops = [self._get(b, v, True) for v in ins.operands]
            new = b.emit(op, ops + [mask], [r.type.with_lanes(self.W) for r in ins.results],
                         ins.attrs)
            for r, n in zip(ins.results, new.results):
                self.env[r] = n
            return
        if op is Op.ANY and ins.operands[0] in self.varying:  # any_lane: of active lanes
            active = b.op(Op.AND, mask.type, self.env[ins.operands[0]], mask)
            self.env[ins.result] = b.op(Op.ANY, ins.result.type, active)
            return
        is_varying = any(r in self.varying for r in ins.results)
        ops = [self._get(b, v, is_varying) for v in ins.operands]
        new = b.emit(op, ops, [self.vtype(r) for r in ins.results], ins.attrs)
        for r, n in zip(ins.results, new.results):
            self.env[r] = n

    def _terminate(self, old: Block, new: Block, types: list[Type], skip: int = 0) -> list[Value]:
        """Map the yielded values of ``old`` into ``new``, broadcasting to ``types``."""
        b = Builder(new, old.instrs[-1].loc)
        vals = old.instrs[-1].operands[skip:]
        return [self._get(b, v, t.lanes > 1) for v, t in zip(vals, types)]

    def _uniform_if(self, ins: Instr, b: Builder, mask: Value, partial: bool) -> None:
        types = [self.vtype(r) for r in ins.results]
        regions = []
        for r in ins.regions:
            nr = self._block(r, mask, [], partial)
            Builder(nr, r.instrs[-1].loc).yield_(*self._terminate(r, nr, types))
            regions.append(nr)
        new = b.emit(Op.IF, [self.env[ins.operands[0]]], types, ins.attrs, regions)
        for r, n in zip(ins.results, new.results):
            self.env[r] = n

    def _varying_if(self, ins: Instr, b: Builder, mask: Value) -> None:
        W = self.W
        cond = self.env[ins.operands[0]]
        types = [self.vtype(r) for r in ins.results]
        not_cond = b.op(Op.NOT, cond.type, cond)
        sides = []
        for region, c in zip(ins.regions, (cond, not_cond)):
            side_mask = b.op(Op.AND, BOOL.with_lanes(W), mask, c)
            if _is_cheap(region):  # cheaper to compute for all lanes than to branch
                self._inline_region(region, b, side_mask)
                sides.append(self._terminate(region, b.block, types))
                continue
            body = self._block(region, side_mask, [], True)
            Builder(body, region.instrs[-1].loc).yield_(*self._terminate(region, body, types))
            skipped = Block()
            sb = Builder(skipped, ins.loc)
            sb.yield_(*[_zero(sb, t) for t in types])
            any_ = b.op(Op.ANY, BOOL, side_mask)
            sides.append(b.emit(Op.IF, [any_], types, {}, [body, skipped]).results)
        for r, t, e in zip(ins.results, *sides):
            self.env[r] = b.op(Op.SELECT, t.type, cond, t, e)

    def _inline_region(self, region: Block, b: Builder, mask: Value) -> None:
        for ins in region.instrs[:-1]:
            b.loc = ins.loc
            self._instr(ins, b, mask, True)

    def _loop(self, ins: Instr, b: Builder, mask: Value, partial: bool) -> None:
        W = self.W
        body = ins.regions[0]
        y = body.instrs[-1]
        types = [self.vtype(a) for a in body.args]
        inits = [self._get(b, v, t.lanes > 1) for v, t in zip(ins.operands, types)]
        args = [Value(t, a.name) for a, t in zip(body.args, types)]
        for a, na in zip(body.args, args):
            self.env[a] = na
        if y.operands[0] not in self.varying:
            nb = self._block(body, mask, args, partial)
            bb = Builder(nb, y.loc)
            bb.yield_(self.env[y.operands[0]], *self._terminate(body, nb, types, skip=1))
            new = b.emit(Op.LOOP, inits, types, ins.attrs, [nb])
            for r, n in zip(ins.results, new.results):
                self.env[r] = n
            return
        # varying trip count: carry an `active` mask, run while any lane is active
        active = Value(BOOL.with_lanes(W), "active")
        nb = self._block(body, active, [active] + args, True)
        bb = Builder(nb, y.loc)
        cont = self.env[y.operands[0]]
        nexts = self._terminate(body, nb, types, skip=1)
        kept = [bb.op(Op.SELECT, t, active, n, a) for n, a, t in zip(nexts, args, types)]
        still = bb.op(Op.AND, BOOL.with_lanes(W), active, cont)
        bb.yield_(bb.op(Op.ANY, BOOL, still), still, *kept)
        new = b.emit(Op.LOOP, [mask] + inits, [BOOL.with_lanes(W)] + types, ins.attrs, [nb])
        for r, n in zip(ins.results, new.results[1:]):
            self.env[r] = n
