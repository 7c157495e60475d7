"""LLVM lowering of IR instructions: types, constants and one rule per op in ``LOWER``.

The semantics are those of ``docs/ir.md``, bit for bit: no fast-math flags, no FMA
contraction, integer division by zero guarded, saturating float-to-int casts.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from typing import Any

import llvmlite.ir as L
import numpy as np

from .. import ir
from ..builtins import F32_INTRINSICS
from ..diagnostics import CompileError
from .llvm_records import emit as emit_record
from .llvm_records import plan as plan_records
from .llvm_records import split_index
from .llvm_runs import consecutive_run

F32 = L.FloatType()
I1 = L.IntType(1)
I8 = L.IntType(8)
I32 = L.IntType(32)
I64 = L.IntType(64)
PTR = L.PointerType()
_SCALAR = {"f32": F32, "i32": I32, "u32": I32, "u64": I64, "bool": I1}
MEM = {"f32": F32, "i32": I32, "u32": I32, "u64": I64, "bool": I8}  # in-memory layout
ALIGN = {"f32": 4, "i32": 4, "u32": 4, "u64": 8, "bool": 1}


def ll_type(t: ir.Type) -> L.Type:
    """The LLVM type of an IR value."""
    if isinstance(t, ir.BufferType):
        return PTR
    if not isinstance(t, ir.ScalarType):
        raise CompileError(f"the LLVM backend sees scalars only, got {t} (run scalarize)")
    base = _SCALAR[t.name]
    return base if t.lanes == 1 else L.VectorType(base, t.lanes)


def mangle(t: L.Type) -> str:
    """The overload suffix of an intrinsic for type ``t`` (``v8f32``, ``i64``, ``p0``)."""
    if isinstance(t, L.VectorType):
        return f"v{t.count}{mangle(t.element)}"
    if isinstance(t, L.FloatType):
        return "f32"
    if isinstance(t, L.IntType):
        return f"i{t.width}"
    if isinstance(t, L.PointerType):
        return "p0"
    raise TypeError(t)


def with_elem(t: L.Type, elem: L.Type) -> L.Type:
    return L.VectorType(elem, t.count) if isinstance(t, L.VectorType) else elem


_SPLATS: dict[tuple[int, str, str], L.Constant] = {}  # (lanes, element type, value) -> splat


def const(ty: L.Type, value) -> L.Constant:
    """A (splatted) constant of LLVM type ``ty``.  Splats are shared: llvmlite formats a
    constant's text once per object, and a kernel uses the same few splats thousands of
    times (the text is the same either way)."""
    if isinstance(ty, L.VectorType):
        c = const(ty.element, value)
        key = (ty.count, str(ty.element), c.get_reference())
        splat = _SPLATS.get(key)
        if splat is None:
            if len(_SPLATS) > 4096:  # a long-lived process: bounded
                _SPLATS.clear()
            splat = _SPLATS[key] = L.Constant(ty, [c] * ty.count)
        return splat
    if isinstance(ty, L.FloatType):
        with np.errstate(over="ignore"):  # round to f32 exactly once; overflow gives inf
            return L.Constant(ty, float(np.float32(value)))
    if isinstance(ty, L.IntType):
        if ty.width == 1:
            return L.Constant(ty, int(bool(value)))
        v = int(value) & ((1 << ty.width) - 1)
        if v >= 1 << (ty.width - 1):
            v -= 1 << ty.width
        return L.Constant(ty, v)
    raise TypeError(ty)


class Lowering:
    """Lowers one IR function body into an LLVM function."""

    def __init__(self, mod: Any, fn: L.Function) -> None:  # mod: llvm._ModuleLowering
        self.m = mod
        self.fn = fn
        self.b = L.IRBuilder(fn.append_basic_block("entry"))
        self.vals: dict[ir.Value, L.Value] = {}
        self._from_memory: dict[ir.Value, bool] = {}
        self.runs: dict[tuple[ir.Value, int], tuple] = {}  # llvm_runs.consecutive_run's checks
        self.records: dict[ir.Instr, Any] = {}  # llvm_records.plan's groups, by member
        self.records_on = getattr(mod, "records", False)  # _ModuleLowering: llvm_records

    # -- helpers ------------------------------------------------------------------------
    def v(self, value: ir.Value) -> L.Value:
        try:
            return self.vals[value]
        except KeyError:
            raise CompileError(f"LLVM backend: use of undefined value {value!r}") from None

    def from_memory(self, value: ir.Value) -> bool:
        """Whether ``value`` is computed from something each lane read from memory or a ray
        query (a gather's index then points anywhere; one from the kernel's own params,
        counters, constants and uniform loads may well walk an array lane by lane).  Values
        carried by loops count as not."""
        memo = self._from_memory
        stack = [value]
        while stack:
            v = stack[-1]
            if v in memo:
                stack.pop()
                continue
            ins = v.owner
            if not isinstance(ins, ir.Instr):
                memo[v] = False
            elif ins.op in _MEMORY_OPS:
                memo[v] = True
            else:
                todo = [o for o in ins.operands if o not in memo]
                if todo:
                    stack.extend(todo)
                    continue
                memo[v] = any(memo[o] for o in ins.operands)
            stack.pop()
        return memo[value]

    def call(self, name: str, ret: L.Type, *args: L.Value) -> L.Value:
        # declared with opaque pointers: a table (a global `[n x float]`) passes for any
        # other pointer, whatever its length
        types = [PTR if isinstance(a.type, L.PointerType) else a.type for a in args]
        return self.b.call(self.m.intrinsic(name, ret, types), list(args))

    def block(self, blk: ir.Block) -> list[L.Value] | None:
        """Lower the instructions of ``blk``; return the operands of its terminator.  What
        the block computes is not reused after it (``runs``: it may not dominate)."""
        outer = self.runs
        self.runs = dict(outer)
        try:
            return self._block(blk)
        finally:
            self.runs = outer

    def _block(self, blk: ir.Block) -> list[L.Value] | None:
        if self.records_on:
            self.records.update(plan_records(self, blk))
        for ins in blk.instrs:
            if ins.op is ir.Op.YIELD:
                return [self.v(o) for o in ins.operands]
            if ins.op is ir.Op.RETURN:
                self.ret([self.v(o) for o in ins.operands])
                return None
            lower = getattr(self.m, "rules", LOWER).get(ins.op)  # a target's own, or LOWER
            if lower is None:
                raise CompileError(f"the LLVM backend cannot lower `{ins.op.value}` "
                                   "(it must be removed by an earlier pass)", ins.loc)
            res = lower(self, ins)
            if res is None:
                continue
            if not isinstance(res, list):
                res = [res]
            for r, lv in zip(ins.results, res):
                self.vals[r] = lv
        return []

    def ret(self, values: list[L.Value]) -> None:
        rty = self.fn.function_type.return_type
        agg = L.Constant(rty, None)
        for i, v in enumerate(values):
            agg = self.b.insert_value(agg, v, i)
        self.b.ret(agg)

    def elem(self, ins: ir.Instr, k: int = 0) -> ir.ScalarType:
        t = ins.operands[k].type
        assert isinstance(t, ir.ScalarType), t
        return t

    def index64(self, idx: ir.Value) -> L.Value:
        """An index operand widened to i64 (sign-extended for i32)."""
        v = self.v(idx)
        t = idx.type
        assert isinstance(t, ir.ScalarType)
        if t.name == "u64":
            return v
        ty = with_elem(v.type, I64)
        return self.b.sext(v, ty) if t.name == "i32" else self.b.zext(v, ty)


# --------------------------------------------------------------------------------------
# Lowering rules (the dispatch table is built at the bottom)


def _lower_const(lw: Lowering, ins: ir.Instr) -> L.Value:
    return const(ll_type(ins.type), ins.attrs["value"])


def _binary(float_op: str, int_op: str) -> Callable[[Lowering, ir.Instr], L.Value]:
    def lower(lw: Lowering, ins: ir.Instr) -> L.Value:
        a, b = (lw.v(o) for o in ins.operands)
        return getattr(lw.b, float_op if lw.elem(ins).is_float else int_op)(a, b)
    return lower


def _lower_divrem(lw: Lowering, ins: ir.Instr) -> L.Value:
    t = lw.elem(ins)
    a, b = (lw.v(o) for o in ins.operands)
    is_div = ins.op is ir.Op.DIV
    if t.is_float:
        return lw.b.fdiv(a, b) if is_div else lw.b.frem(a, b)
    zero, one = const(a.type, 0), const(a.type, 1)
    bz = lw.b.icmp_unsigned("==", b, zero)
    bad = bz
    if t.is_signed:
        # INT_MIN / -1 overflows: divide by 1 instead (INT_MIN / 1 = INT_MIN, INT_MIN % 1 = 0)
        ovf = lw.b.and_(lw.b.icmp_signed("==", a, const(a.type, -(1 << 31))),
                        lw.b.icmp_signed("==", b, const(a.type, -1)))
        bad = lw.b.or_(bz, ovf)
    safe = lw.b.select(bad, one, b)
    if t.is_signed:
        r = lw.b.sdiv(a, safe) if is_div else lw.b.srem(a, safe)
    else:
        r = lw.b.udiv(a, safe) if is_div else lw.b.urem(a, safe)
    return lw.b.select(bz, zero, r)


def _lower_neg(lw: Lowering, ins: ir.Instr) -> L.Value:
    a = lw.v(ins.operands[0])
    if lw.elem(ins).is_float:
        return lw.b.fneg(a)
    return lw.b.sub(const(a.type, 0), a)


def _lower_not(lw: Lowering, ins: ir.Instr) -> L.Value:
    a = lw.v(ins.operands[0])
    return lw.b.xor(a, const(a.type, -1))


def _lower_shift(lw: Lowering, ins: ir.Instr) -> L.Value:
    t = lw.elem(ins)
    a, s = (lw.v(o) for o in ins.operands)
    if s.type != a.type:  # be lenient about the amount's integer type
        src_bits = s.type.element.width if isinstance(s.type, L.VectorType) else s.type.width
        if src_bits > t.bits:
            s = lw.b.trunc(s, a.type)
        else:
            s = lw.b.zext(s, a.type)
    s = lw.b.and_(s, const(a.type, t.bits - 1))
    if ins.op is ir.Op.SHL:
        return lw.b.shl(a, s)
    return lw.b.ashr(a, s) if t.is_signed else lw.b.lshr(a, s)


_FCMP = {ir.Op.EQ: "==", ir.Op.LT: "<", ir.Op.LE: "<=", ir.Op.GT: ">", ir.Op.GE: ">="}
_ICMP = {ir.Op.EQ: "==", ir.Op.NE: "!=", ir.Op.LT: "<", ir.Op.LE: "<=", ir.Op.GT: ">",
         ir.Op.GE: ">="}


def _cmp(lw: Lowering, op: ir.Op, t: ir.ScalarType, a: L.Value, b: L.Value) -> L.Value:
    if t.is_float:
        if op is ir.Op.NE:
            return lw.b.fcmp_unordered("!=", a, b)
        return lw.b.fcmp_ordered(_FCMP[op], a, b)
    if t.is_signed:
        return lw.b.icmp_signed(_ICMP[op], a, b)
    return lw.b.icmp_unsigned(_ICMP[op], a, b)


def _lower_cmp(lw: Lowering, ins: ir.Instr) -> L.Value:
    a, b = (lw.v(o) for o in ins.operands)
    return _cmp(lw, ins.op, lw.elem(ins), a, b)


def _lower_minmax(lw: Lowering, ins: ir.Instr) -> L.Value:
    a, b = (lw.v(o) for o in ins.operands)
    c = _cmp(lw, ir.Op.LT if ins.op is ir.Op.MIN else ir.Op.GT, lw.elem(ins), a, b)
    return lw.b.select(c, a, b)


def _lower_select(lw: Lowering, ins: ir.Instr) -> L.Value:
    c, a, b = (lw.v(o) for o in ins.operands)  # a scalar i1 may select whole vectors
    return lw.b.select(c, a, b)


def _unary_intrinsic(name: str) -> Callable[[Lowering, ir.Instr], L.Value]:
    def lower(lw: Lowering, ins: ir.Instr) -> L.Value:
        a = lw.v(ins.operands[0])
        return lw.call(f"llvm.{name}.{mangle(a.type)}", a.type, a)
    return lower


def _lower_abs(lw: Lowering, ins: ir.Instr) -> L.Value:
    t = lw.elem(ins)
    a = lw.v(ins.operands[0])
    if t.is_float:
        return lw.call(f"llvm.fabs.{mangle(a.type)}", a.type, a)
    if not t.is_signed:
        return a
    return lw.call(f"llvm.abs.{mangle(a.type)}", a.type, a, const(I1, 0))


def _lower_cast(lw: Lowering, ins: ir.Instr) -> L.Value:
    src, dst = lw.elem(ins), ins.type
    assert isinstance(dst, ir.ScalarType)
    a = lw.v(ins.operands[0])
    dty = ll_type(dst)
    if src.name == dst.name or {src.name, dst.name} == {"i32", "u32"}:
        return a
    b = lw.b
    if dst.name == "bool":
        if src.is_float:
            return b.fcmp_unordered("!=", a, const(a.type, 0.0))
        return b.icmp_unsigned("!=", a, const(a.type, 0))
    if src.name == "bool":
        return b.uitofp(a, dty) if dst.is_float else b.zext(a, dty)
    if src.is_float:  # -> int: truncate toward zero, saturate, NaN -> 0
        return _saturating_fptoint(lw, a, dst, dty)
    if dst.is_float:
        return b.sitofp(a, dty) if src.is_signed else b.uitofp(a, dty)
    if dst.bits > src.bits:
        return b.sext(a, dty) if src.is_signed else b.zext(a, dty)
    return b.trunc(a, dty)


def _saturating_fptoint(lw: Lowering, a: L.Value, dst: ir.ScalarType, dty: L.Type) -> L.Value:
    """``llvm.fpto[su]i.sat`` spelled as clamp + convert + select: the intrinsic is
    scalarized on vectors by LLVM, this form stays in vector registers."""
    b = lw.b
    lo = -(2.0 ** (dst.bits - 1)) if dst.is_signed else 0.0
    hi = 2.0 ** (dst.bits - 1) if dst.is_signed else 2.0 ** dst.bits
    below_hi = hi * (1.0 - 2.0 ** -24)  # the largest f32 under hi
    top = (1 << (dst.bits - 1)) - 1 if dst.is_signed else (1 << dst.bits) - 1
    x = b.select(b.fcmp_ordered(">", a, const(a.type, below_hi)), const(a.type, below_hi), a)
    x = b.select(b.fcmp_ordered("<", x, const(a.type, lo)), const(a.type, lo), x)
    x = b.select(b.fcmp_unordered("uno", x, x), const(a.type, 0.0), x)
    r = b.fptosi(x, dty) if dst.is_signed else b.fptoui(x, dty)
    return b.select(b.fcmp_ordered(">=", a, const(a.type, hi)), const(dty, top), r)


def _lower_bitcast(lw: Lowering, ins: ir.Instr) -> L.Value:
    a = lw.v(ins.operands[0])
    dty = ll_type(ins.type)
    return a if a.type == dty else lw.b.bitcast(a, dty)


def _lower_broadcast(lw: Lowering, ins: ir.Instr) -> L.Value:
    a = lw.v(ins.operands[0])
    dty = ll_type(ins.type)
    if not isinstance(dty, L.VectorType) or isinstance(a.type, L.VectorType):
        return a
    return lw.m.splat(lw.b, a, dty.count)


def _lower_any(lw: Lowering, ins: ir.Instr) -> L.Value:
    a = lw.v(ins.operands[0])
    if not isinstance(a.type, L.VectorType):
        return a
    return lw.call(f"llvm.vector.reduce.or.{mangle(a.type)}", I1, a)


def _lower_lane(lw: Lowering, ins: ir.Instr) -> L.Value:
    ty = ll_type(ins.type)
    if not isinstance(ty, L.VectorType):
        return const(ty, 0)
    return L.Constant(ty, [L.Constant(ty.element, i) for i in range(ty.count)])


def _lower_table(lw: Lowering, ins: ir.Instr) -> L.Value:
    """A read-only table: a private constant global, one per distinct contents."""
    values = [float(np.float32(v)) for v in ins.attrs["values"]]
    mod = lw.b.module
    name = "rdsl_table_" + hashlib.sha1(np.asarray(values, np.float32).tobytes()).hexdigest()[:16]
    if name not in mod.globals:
        aty = L.ArrayType(L.FloatType(), len(values))
        g = L.GlobalVariable(mod, aty, name)
        g.global_constant = True
        g.linkage = "private"
        g.initializer = L.Constant(aty, values)
        g.align = 16
    return mod.globals[name]


def _buf_elem(buf: ir.Value) -> ir.ScalarType:
    t = buf.type
    assert isinstance(t, ir.BufferType), t
    return t.elem


def _from_mem(lw: Lowering, v: L.Value, elem: ir.ScalarType) -> L.Value:
    if elem.name == "bool":
        return lw.b.icmp_unsigned("!=", v, const(v.type, 0))
    return v


def _to_mem(lw: Lowering, v: L.Value, elem: ir.ScalarType) -> L.Value:
    if elem.name == "bool":
        return lw.b.zext(v, with_elem(v.type, I8))
    return v


def _gep(lw: Lowering, base: L.Value, idx: L.Value, ety: L.Type) -> L.Value:
    """``getelementptr ety, ptr base, idx``; a vector of pointers for a vector index."""
    g = lw.b.gep(base, [idx], source_etype=ety)
    if isinstance(idx.type, L.VectorType):
        g.type = L.VectorType(PTR, idx.type.count)  # llvmlite assumes a scalar result
    return g


def _lower_load(lw: Lowering, ins: ir.Instr) -> L.Value:
    buf, idx = ins.operands
    e = _buf_elem(buf)
    p = lw.b.gep(lw.v(buf), [lw.index64(idx)], source_etype=MEM[e.name])
    return _from_mem(lw, lw.b.load(p, typ=MEM[e.name], align=ALIGN[e.name]), e)


def _lower_store(lw: Lowering, ins: ir.Instr) -> None:
    buf, idx, val = ins.operands
    e = _buf_elem(buf)
    p = lw.b.gep(lw.v(buf), [lw.index64(idx)], source_etype=MEM[e.name])
    lw.b.store(_to_mem(lw, lw.v(val), e), p, align=ALIGN[e.name])


# ops whose results vary per lane with memory (a uniform `load` is the same for every lane,
# so an index built from one still walks lane by lane)
_MEMORY_OPS = frozenset({ir.Op.GATHER, ir.Op.INTERSECT, ir.Op.OCCLUDED})


def _lower_gather(lw: Lowering, ins: ir.Instr) -> L.Value:
    buf, idx, mask = ins.operands
    e = _buf_elem(buf)
    mty = MEM[e.name]
    group = lw.records.get(ins)
    if group is not None:  # a field of a record: llvm_records
        k = split_index(idx)[1]
        if not group.values:
            emit_record(lw, group, ins, k)
        return _from_mem(lw, group.values[k], e)
    m = lw.v(mask)
    p = _gep(lw, lw.v(buf), lw.index64(idx), mty)
    if not isinstance(m.type, L.VectorType):  # W == 1: a branch around the load
        return _from_mem(lw, lw.m.guarded_load(lw.b, p, mty, ALIGN[e.name], m), e)
    vty = L.VectorType(mty, m.type.count)
    if idx.type.name != "i32" or lw.from_memory(idx):
        r = lw.call(f"llvm.masked.gather.{mangle(vty)}.{mangle(p.type)}", vty,
                    p, const(I32, ALIGN[e.name]), m, const(vty, 0))
        return _from_mem(lw, r, e)
    return _from_mem(lw, _gather_or_load(lw, lw.v(buf), idx, p, m, vty, ALIGN[e.name]), e)


def _gather_or_load(lw: Lowering, base: L.Value, idx: ir.Value, ptrs: L.Value, m: L.Value,
                    vty: L.Type, align: int) -> L.Value:
    """A masked gather, or a masked vector load when the lanes' i32 indices turn out to be
    consecutive (``idx[k] == idx[0] + k``, checked at run time): the same values, from one
    load instead of W.  Kernels that walk arrays lane by lane (the film's gather over a
    batch of samples) take the load; other indices pay a compare and a branch, so indices
    read from memory (a triangle's vertices) skip the check."""
    b = lw.b
    first, contiguous = consecutive_run(lw, idx, m)
    load_bb = b.append_basic_block("contiguous")
    gather_bb = b.append_basic_block("gather")
    join_bb = b.append_basic_block("gathered")
    b.cbranch(contiguous, load_bb, gather_bb)
    b.position_at_end(load_bb)
    p0 = b.gep(base, [b.sext(first, I64)], source_etype=vty.element)
    loaded = lw.call(f"llvm.masked.load.{mangle(vty)}.p0", vty, p0, const(I32, align), m,
                     const(vty, 0))
    b.branch(join_bb)
    b.position_at_end(gather_bb)
    gathered = lw.call(f"llvm.masked.gather.{mangle(vty)}.{mangle(ptrs.type)}", vty,
                       ptrs, const(I32, align), m, const(vty, 0))
    b.branch(join_bb)
    b.position_at_end(join_bb)
    r = b.phi(vty)
    r.add_incoming(loaded, load_bb)
    r.add_incoming(gathered, gather_bb)
    return r


def _lower_scatter(lw: Lowering, ins: ir.Instr) -> None:
    buf, idx, val, mask = ins.operands
    e = _buf_elem(buf)
    mty = MEM[e.name]
    m = lw.v(mask)
    p = _gep(lw, lw.v(buf), lw.index64(idx), mty)
    v = _to_mem(lw, lw.v(val), e)
    if not isinstance(m.type, L.VectorType):
        with lw.b.if_then(m):
            lw.b.store(v, p, align=ALIGN[e.name])
        return
    scatter = f"llvm.masked.scatter.{mangle(v.type)}.{mangle(p.type)}"
    if idx.type.name != "i32" or lw.from_memory(idx):
        lw.call(scatter, L.VoidType(), v, p, const(I32, ALIGN[e.name]), m)
        return
    # as _gather_or_load: a masked vector store where the indices turn out consecutive (the
    # adjoint's per-lane tape rows, interleaved: passes/ad_checkpoint.py)
    b = lw.b
    first, contiguous = consecutive_run(lw, idx, m)
    with b.if_else(contiguous) as (store, other):
        with store:
            p0 = b.gep(lw.v(buf), [b.sext(first, I64)], source_etype=mty)
            lw.call(f"llvm.masked.store.{mangle(v.type)}.p0", L.VoidType(), v, p0,
                    const(I32, ALIGN[e.name]), m)
        with other:
            lw.call(scatter, L.VoidType(), v, p, const(I32, ALIGN[e.name]), m)


def _lower_if(lw: Lowering, ins: ir.Instr) -> list[L.Value]:
    cond = lw.v(ins.operands[0])
    then_r, else_r = ins.regions
    b = lw.b
    then_bb = b.append_basic_block("then")
    else_bb = b.append_basic_block("else")
    merge_bb = b.append_basic_block("endif")
    b.cbranch(cond, then_bb, else_bb)
    incoming = []
    for bb, region in ((then_bb, then_r), (else_bb, else_r)):
        b.position_at_end(bb)
        vals = lw.block(region) or []
        incoming.append((vals, b.block))
        b.branch(merge_bb)
    b.position_at_end(merge_bb)
    out = []
    for i, r in enumerate(ins.results):
        phi = b.phi(ll_type(r.type))
        for vals, bb in incoming:
            phi.add_incoming(vals[i], bb)
        out.append(phi)
    return out


def _lower_loop(lw: Lowering, ins: ir.Instr) -> list[L.Value]:
    (body,) = ins.regions
    b = lw.b
    pre = b.block
    body_bb = b.append_basic_block("loop")
    exit_bb = b.append_basic_block("endloop")
    b.branch(body_bb)
    b.position_at_end(body_bb)
    phis = []
    for arg, init in zip(body.args, ins.operands):
        phi = b.phi(ll_type(arg.type))
        phi.add_incoming(lw.v(init), pre)
        lw.vals[arg] = phi
        phis.append(phi)
    vals = lw.block(body) or []
    cont, nxt = vals[0], vals[1:]
    latch = b.block
    for phi, v in zip(phis, nxt):
        phi.add_incoming(v, latch)
    b.cbranch(cont, body_bb, exit_bb)
    b.position_at_end(exit_bb)
    return list(nxt)


LOWER: dict[ir.Op, Callable[[Lowering, ir.Instr], L.Value | list[L.Value] | None]] = {
    ir.Op.CONST: _lower_const,
    ir.Op.ADD: _binary("fadd", "add"),
    ir.Op.SUB: _binary("fsub", "sub"),
    ir.Op.MUL: _binary("fmul", "mul"),
    ir.Op.DIV: _lower_divrem,
    ir.Op.REM: _lower_divrem,
    ir.Op.NEG: _lower_neg,
    ir.Op.AND: _binary("and_", "and_"),
    ir.Op.OR: _binary("or_", "or_"),
    ir.Op.XOR: _binary("xor", "xor"),
    ir.Op.NOT: _lower_not,
    ir.Op.SHL: _lower_shift,
    ir.Op.SHR: _lower_shift,
    **{op: _lower_cmp for op in ir.CMP_OPS},
    ir.Op.SELECT: _lower_select,
    **{op: _unary_intrinsic(i.llvm) for op, i in F32_INTRINSICS.items()},
    ir.Op.ABS: _lower_abs,
    ir.Op.MIN: _lower_minmax,
    ir.Op.MAX: _lower_minmax,
    ir.Op.CAST: _lower_cast,
    ir.Op.BITCAST: _lower_bitcast,
    ir.Op.BROADCAST: _lower_broadcast,
    ir.Op.ANY: _lower_any,
    ir.Op.LANE: _lower_lane,
    ir.Op.LOAD: _lower_load,
    ir.Op.TABLE: _lower_table,
    ir.Op.STORE: _lower_store,
    ir.Op.GATHER: _lower_gather,
    ir.Op.SCATTER: _lower_scatter,
    ir.Op.IF: _lower_if,
    ir.Op.LOOP: _lower_loop,
}

