"""The C entry points of a kernel, in LLVM: ``rdsl_<name>_range(begin, end, args..., outs...,
mask)`` loops over ``[begin, end)`` in steps of W and calls the (always inlined) body;
``rdsl_<name>(n, ...)`` calls it on ``[0, n)``.

Full vectors use plain unaligned loads and stores, in two copies of the loop: one for
``mask == NULL`` (every lane active) and one that reads the user's mask and stores outputs
with ``llvm.masked.store``.  The last partial vector uses masked loads and stores with the lane
mask ``i + lane < end``.  Uniform results are broadcast to every lane.
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir
from ..diagnostics import CompileError
from .base import CArg, c_arg_names, c_args, c_name, split_params
from .llvm_ops import ALIGN, I1, I8, I32, I64, MEM, PTR, const, mangle, with_elem


def emit_kernel(ml: Any, fn: ir.Function, body: L.Function) -> None:
    """Emit ``rdsl_<name>_range`` and ``rdsl_<name>`` for kernel ``fn`` whose lowered body
    function is ``body``.  ``ml`` is the module lowering (module, target, helpers)."""
    params, mask_param = split_params(fn)
    if mask_param is None:
        raise CompileError(f"kernel `{fn.name}` has no execution mask parameter "
                           "(run vectorize first)", fn.loc)
    args = c_args(fn)

    def c_ty(a: CArg) -> L.Type:
        return PTR if a.kind != "uniform" else MEM[a.dtype]

    cname = "rdsl_" + c_name(fn.name)
    arg_tys = [c_ty(a) for a in args] + [PTR]
    rng = L.Function(ml.mod, L.FunctionType(L.VoidType(), [I64, I64] + arg_tys),
                     cname + "_range")
    ml.attrs(rng)
    rng.attributes.add("noinline")  # one copy of the loops, shared by both entry points
    _range_fn(ml, rng, body, args)

    top = L.Function(ml.mod, L.FunctionType(L.VoidType(), [I64] + arg_tys), cname)
    ml.attrs(top)
    b = L.IRBuilder(top.append_basic_block("entry"))
    b.call(rng, [const(I64, 0), top.args[0], *top.args[1:]])
    b.ret_void()

def _range_fn(ml: Any, rng: L.Function, body: L.Function, args: list[CArg]) -> None:
    """The loop over [begin, end): full vectors (with and without a user mask), then the
    tail with masked loads and stores."""
    _RangeLoop(ml, rng, body, args).emit()


class _RangeLoop:
    """Builds the body of ``rdsl_<name>_range``: its arguments, the loads and stores of one
    vector of elements, and the three loops (all lanes, user mask, tail)."""

    def __init__(self, ml: Any, rng: L.Function, body: L.Function, args: list[CArg]) -> None:
        self.ml, self.rng, self.body, self.W = ml, rng, body, ml.width
        self.begin, self.end = rng.args[0], rng.args[1]
        cargs = list(rng.args[2:-1])
        self.user_mask = rng.args[-1]
        for name, la in zip(c_arg_names(args), cargs):
            la.name = name
        self.begin.name, self.end.name, self.user_mask.name = "begin", "end", "mask"
        n_in = sum(a.kind != "output" for a in args)
        self.ins_args, self.outs = args[:n_in], args[n_in:]
        self.in_vals, self.out_ptrs = cargs[:n_in], cargs[n_in:]
        self.b = L.IRBuilder(rng.append_basic_block("entry"))
        self.mask_ty = L.VectorType(I1, self.W) if self.W > 1 else I1

    def emit(self) -> None:
        b, W = self.b, self.W
        # uniform params are converted once, outside the loops
        self.uniforms = []
        for a, v in zip(self.ins_args, self.in_vals):
            if a.kind == "uniform" and a.dtype == "bool":
                v = b.icmp_unsigned("!=", v, const(I8, 0))
            self.uniforms.append(v)
        count = b.sub(self.end, self.begin)
        count = b.select(b.icmp_signed("<", count, const(I64, 0)), const(I64, 0), count)
        self.full_end = b.add(self.begin, b.and_(count, const(I64, ~(W - 1))))
        self.has_mask = b.icmp_unsigned("!=", self.user_mask, L.Constant(PTR, None))
        tail_bb = self.rng.append_basic_block("tail")
        loop_a = self.rng.append_basic_block("all.head")
        loop_m = self.rng.append_basic_block("masked.head")
        b.cbranch(self.has_mask, loop_m, loop_a)
        entry = b.block
        # full vectors, no user mask / with user mask
        for head, masked in ((loop_a, False), (loop_m, True)):
            self.full_loop(entry, head, masked, tail_bb)
        # the tail: fewer than W elements, masked loads and stores
        b.position_at_end(tail_bb)
        if W == 1:
            b.ret_void()
            return
        self.tail()

    def vec_ty(self, dtype: str) -> L.Type:
        t = MEM[dtype]
        return L.VectorType(t, self.W) if self.W > 1 else t

    def gep(self, ptr: L.Value, dtype: str, i: L.Value) -> L.Value:
        return self.b.gep(ptr, [i], source_etype=MEM[dtype])

    def masked_load(self, ty: L.Type, p: L.Value, align: int, lanes: L.Value) -> L.Value:
        return self.b.call(self.ml.intrinsic(f"llvm.masked.load.{mangle(ty)}.p0", ty,
                                             [PTR, I32, self.mask_ty, ty]),
                           [p, const(I32, align), lanes, const(ty, 0)])

    def load_in(self, a: CArg, ptr: L.Value, i: L.Value, lanes: L.Value | None) -> L.Value:
        """Load W elements of a varying input starting at i (lanes: tail mask or None)."""
        b = self.b
        ty = self.vec_ty(a.dtype)
        p = self.gep(ptr, a.dtype, i)
        if lanes is None:
            v = b.load(p, typ=ty, align=ALIGN[a.dtype])
        else:
            v = self.masked_load(ty, p, ALIGN[a.dtype], lanes)
        if a.dtype == "bool":
            v = b.icmp_unsigned("!=", v, const(ty, 0))
        return v

    def call_body(self, i: L.Value, exec_mask: L.Value, lanes: L.Value | None) -> list:
        vals = [self.load_in(a, ptr, i, lanes) if a.kind == "varying" else u
                for a, ptr, u in zip(self.ins_args, self.in_vals, self.uniforms)]
        res = self.b.call(self.body, vals + [exec_mask])
        return [self.b.extract_value(res, k) for k in range(len(self.outs))]

    def store_outs(self, i: L.Value, results: list, store_mask: L.Value | None) -> None:
        b, W = self.b, self.W
        for a, ptr, v in zip(self.outs, self.out_ptrs, results):
            if a.dtype == "bool":
                v = b.zext(v, with_elem(v.type, I8))
            if W > 1 and not isinstance(v.type, L.VectorType):
                v = self.ml.splat(b, v, W)
            p = self.gep(ptr, a.dtype, i)
            if store_mask is None:
                b.store(v, p, align=ALIGN[a.dtype])
            elif W == 1:
                with b.if_then(store_mask):
                    b.store(v, p, align=ALIGN[a.dtype])
            else:
                b.call(self.ml.intrinsic(f"llvm.masked.store.{mangle(v.type)}.p0",
                                         L.VoidType(), [v.type, PTR, I32, self.mask_ty]),
                       [v, p, const(I32, ALIGN[a.dtype]), store_mask])

    def load_user_mask(self, i: L.Value, lanes: L.Value | None) -> L.Value:
        ty = self.vec_ty("bool")
        p = self.gep(self.user_mask, "bool", i)
        if lanes is None:
            m = self.b.load(p, typ=ty, align=1)
        else:
            m = self.masked_load(ty, p, 1, lanes)
        return self.b.icmp_unsigned("!=", m, const(ty, 0))

    def full_loop(self, entry: L.Block, head: L.Block, masked: bool, tail_bb: L.Block) -> None:
        b = self.b
        b.position_at_end(head)
        i = b.phi(I64, name="i")
        i.add_incoming(self.begin, entry)
        body_bb = self.rng.append_basic_block(("masked" if masked else "all") + ".body")
        b.cbranch(b.icmp_signed("<", i, self.full_end), body_bb, tail_bb)
        b.position_at_end(body_bb)
        um = self.load_user_mask(i, None) if masked else None
        results = self.call_body(i, um if masked else const(self.mask_ty, 1), None)
        self.store_outs(i, results, um)
        i.add_incoming(b.add(i, const(I64, self.W)), b.block)
        b.branch(head)

    def tail(self) -> None:
        b, W, rng, full_end = self.b, self.W, self.rng, self.full_end
        rest = b.sub(self.end, full_end)
        done = rng.append_basic_block("done")
        work = rng.append_basic_block("tail.body")
        b.cbranch(b.icmp_signed(">", rest, const(I64, 0)), work, done)
        b.position_at_end(done)
        b.ret_void()
        b.position_at_end(work)
        lane_ids = L.Constant(L.VectorType(I32, W), [L.Constant(I32, k) for k in range(W)])
        lanes = b.icmp_signed("<", lane_ids, self.ml.splat(b, b.trunc(rest, I32), W))
        with_m = rng.append_basic_block("tail.mask")
        join = rng.append_basic_block("tail.join")
        pre = b.block
        b.cbranch(self.has_mask, with_m, join)
        b.position_at_end(with_m)
        um = b.and_(lanes, self.load_user_mask(full_end, lanes))
        b.branch(join)
        b.position_at_end(join)
        exec_mask = b.phi(self.mask_ty)
        exec_mask.add_incoming(lanes, pre)
        exec_mask.add_incoming(um, with_m)
        results = self.call_body(full_end, exec_mask, lanes)
        self.store_outs(full_end, results, exec_mask)
        b.branch(done)
