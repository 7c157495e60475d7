"""The C entry points of a kernel, in LLVM: ``rdsl_<name>_range(begin, end, args..., outs...,
mask, mask_stride)`` loops over ``[begin, end)`` in steps of W and calls the (always inlined)
body; ``rdsl_<name>(n, ...)`` calls it on ``[0, n)``.  Every array comes with its byte stride
(see :func:`rdsl.compiler.backends.base.c_params`).

Full vectors are loaded and stored whole, in two copies of the loop: one for ``mask == NULL``
(every lane active) and one that reads the user's mask and stores outputs under it.  The last
partial vector uses masked loads and stores with the lane mask ``i + lane < end``.  How one
vector of an array is reached (plain vector access when it is contiguous, shuffles or gathers
when strided) is ``llvm_arrays``' job; the body is inlined once per loop either way.  Uniform
results are broadcast to every lane.
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir
from ..diagnostics import CompileError
from .base import CArg, c_arg_names, c_args, c_name, split_params
from .llvm_arrays import SHUFFLE_FACTORS, ArrayAccess, ArrayGroup, StridedArray
from .llvm_ops import I8, I32, I64, MEM, PTR, const, with_elem

# A kernel of more arrays than this reads and writes strided ones by gathers and scatters
# only (see _RangeLoop.strided_how): cut the CPU time of compiling the principled BSDF's
# spectral_polarized test harness (64 outputs) from 8.9 s to 6.2 s.
SHUFFLED_ARRAYS_LIMIT = 16


def emit_kernel(ml: Any, fn: ir.Function, body: L.Function) -> None:
    """Emit ``rdsl_<name>_range`` and ``rdsl_<name>`` for kernel ``fn`` whose lowered body
    function is ``body``.  ``ml`` is the module lowering (module, target, helpers)."""
    params, mask_param = split_params(fn)
    if mask_param is None:
        raise CompileError(f"kernel `{fn.name}` has no execution mask parameter "
                           "(run vectorize first)", fn.loc)
    args = c_args(fn)

    arg_tys: list[L.Type] = []
    for a in args:
        arg_tys.append(PTR if a.kind != "uniform" else MEM[a.dtype])
        if a.strided:
            arg_tys.append(I64)  # the byte stride
    arg_tys += [PTR, I64]  # the mask and its stride
    cname = "rdsl_" + c_name(fn.name)
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
    vector of elements (through :class:`ArrayAccess`, for any strides), and four loops: over
    full vectors of contiguous arrays with every lane active or under the user's mask, over
    full vectors of strided arrays (either), and the tail."""

    def __init__(self, ml: Any, rng: L.Function, body: L.Function, args: list[CArg]) -> None:
        self.ml, self.rng, self.body, self.W = ml, rng, body, ml.width
        self.begin, self.end = rng.args[0], rng.args[1]
        self.begin.name, self.end.name = "begin", "end"
        it = iter(rng.args[2:])
        self.arrays: dict[int, StridedArray] = {}  # position in args -> its array
        values: list[L.Value] = []
        for k, (a, name) in enumerate(zip(args, c_arg_names(args))):
            v = next(it)
            v.name = name
            values.append(v)
            if a.strided:
                stride = next(it)
                stride.name = name + "_stride"
                self.arrays[k] = StridedArray(a.dtype, v, stride)
        mask, mask_stride = next(it), next(it)
        mask.name, mask_stride.name = "mask", "mask_stride"
        self.user_mask = StridedArray("bool", mask, mask_stride)
        n_in = sum(a.kind != "output" for a in args)
        self.ins_args, self.outs = args[:n_in], args[n_in:]
        self.in_vals = values[:n_in]
        self.out_arrays = [self.arrays[k] for k in range(n_in, len(args))]
        self.out_groups = _vector_groups(self.outs, list(self.out_arrays))
        self.in_groups = _vector_groups(self.ins_args,
                                        [self.arrays.get(k) for k in range(n_in)])
        self.b = L.IRBuilder(rng.append_basic_block("entry"))
        self.mem = ArrayAccess(ml, rng, self.b, self.end)
        self.mask_ty = self.mem.mask_ty

    def emit(self) -> None:
        b, W = self.b, self.W
        # uniform params are converted and arrays classified once, outside the loops
        self.uniforms = []
        for a, v in zip(self.ins_args, self.in_vals):
            if a.kind == "uniform" and a.dtype == "bool":
                v = b.icmp_unsigned("!=", v, const(I8, 0))
            self.uniforms.append(v)
        for arr in [*self.arrays.values(), self.user_mask]:
            self.mem.prepare(arr)
        if W > 1 and self.strided_how() == "strided":
            for g in [*self.in_groups.values(), *self.out_groups.values()]:
                self.mem.prepare_group(g)
        count = b.sub(self.end, self.begin)
        count = b.select(b.icmp_signed("<", count, const(I64, 0)), const(I64, 0), count)
        self.full_end = b.add(self.begin, b.and_(count, const(I64, ~(W - 1))))
        self.has_mask = b.icmp_unsigned("!=", self.user_mask.ptr, L.Constant(PTR, None))
        tail_bb = self.rng.append_basic_block("tail")
        fast = self.rng.append_basic_block("contiguous")
        loop_a = self.rng.append_basic_block("all.head")
        loop_m = self.rng.append_basic_block("masked.head")
        if W == 1:  # one element per step: its address is all a stride changes
            b.branch(fast)
        else:
            loop_s = self.rng.append_basic_block("strided.head")
            b.cbranch(self.all_contiguous(), fast, loop_s)
            self.full_loop(b.block, loop_s, "either", tail_bb, self.strided_how())
        b.position_at_end(fast)
        b.cbranch(self.has_mask, loop_m, loop_a)
        # full vectors of contiguous arrays, without and with a user mask
        self.full_loop(fast, loop_a, "all", tail_bb, "contiguous")
        self.full_loop(fast, loop_m, "masked", tail_bb, "contiguous")
        b.position_at_end(tail_bb)
        if W == 1:
            b.ret_void()
            return
        # the tail: fewer than W elements, masked loads and stores
        self.tail()

    def strided_how(self) -> str:
        """How the strided loop reaches its arrays: wide loads and shuffles where a stride
        allows ("strided"), or, for kernels of many arrays, gathers and scatters only
        ("any"): a five-way branch per array access made a BSDF test harness's 64
        Mueller outputs most of its LLVM compile time."""
        return "any" if len(self.arrays) > SHUFFLED_ARRAYS_LIMIT else "strided"

    def all_contiguous(self) -> L.Value:
        """i1: every array (the mask too, when given) is contiguous and aligned.  Such calls
        run loops with plain accesses only: a branch per access costs AVX2 up to 16%."""
        b = self.b
        ok = b.or_(b.not_(self.has_mask), self.user_mask.contiguous)
        for arr in self.arrays.values():
            ok = b.and_(ok, arr.contiguous)
        return ok

    def load_in(self, a: CArg, arr: StridedArray, i: L.Value, lanes: L.Value | None,
                how: str) -> L.Value:
        """Load W elements of a varying input starting at i (lanes: tail mask or None)."""
        return self.as_bool(a, self.mem.load(arr, i, lanes, how))

    def as_bool(self, a: CArg, v: L.Value) -> L.Value:
        if a.dtype == "bool":
            v = self.b.icmp_unsigned("!=", v, const(v.type, 0))
        return v

    def call_body(self, i: L.Value, exec_mask: L.Value, lanes: L.Value | None,
                  how: str) -> list:
        vals = list(self.uniforms)
        groups = self.in_groups if how == "strided" else {}
        k = 0
        while k < len(self.ins_args):
            a, g = self.ins_args[k], groups.get(k)
            if g is not None:  # maybe the columns of one C-order (N, k) array: one load
                ks = range(k, k + len(g.members))
                vs = self.mem.branch(
                    g.ok, lambda g=g, a=a: [self.as_bool(a, v)
                                            for v in self.mem.load_group(g, i)],
                    lambda ks=ks, a=a: [self.load_in(a, self.arrays[j], i, None, how)
                                        for j in ks])
                vals[k:k + len(ks)] = vs
                k += len(ks)
                continue
            if a.kind == "varying":
                vals[k] = self.load_in(a, self.arrays[k], i, lanes, how)
            k += 1
        res = self.b.call(self.body, vals + [exec_mask])
        return [self.b.extract_value(res, k) for k in range(len(self.outs))]

    def store_outs(self, i: L.Value, results: list, store_mask: L.Value | None,
                   how: str, masked: L.Value | None = None) -> None:
        b, W = self.b, self.W
        vals = []
        for a, v in zip(self.outs, results):
            if a.dtype == "bool":
                v = b.zext(v, with_elem(v.type, I8))
            if W > 1 and not isinstance(v.type, L.VectorType):
                v = self.ml.splat(b, v, W)
            vals.append(v)
        done: set[int] = set()
        for k, arr in enumerate(self.out_arrays):
            g = self.out_groups.get(k) if how == "strided" else None
            if k in done:
                continue
            if g is None:
                self.mem.store(arr, i, vals[k], store_mask, how, masked)
                continue
            ks = range(k, k + len(g.members))
            done.update(ks)

            def apart(ks: range = ks) -> None:
                for j in ks:
                    self.mem.store(self.out_arrays[j], i, vals[j], store_mask, how, masked)

            # the columns of one C-order (N, k) array: interleaved, one store of them all
            self.mem.branch(g.ok, lambda g=g, ks=ks: self.mem.store_group(
                g, i, [vals[j] for j in ks], store_mask, masked), apart)

    def load_user_mask(self, i: L.Value, lanes: L.Value | None, how: str) -> L.Value:
        m = self.mem.load(self.user_mask, i, lanes, how)
        return self.b.icmp_unsigned("!=", m, const(m.type, 0))

    def full_loop(self, entry: L.Block, head: L.Block, mask: str, tail_bb: L.Block,
                  how: str) -> None:
        """The loop over full vectors from ``begin``, entered from ``entry``.  ``mask``:
        "all" (every lane active), "masked" (the user's mask) or "either" (the user's mask
        when given, a run-time choice); ``how`` the arrays are reached (see
        :meth:`ArrayAccess.load`)."""
        b = self.b
        b.position_at_end(head)
        i = b.phi(I64, name="i")
        i.add_incoming(self.begin, entry)
        body_bb = self.rng.append_basic_block(head.name.replace("head", "body"))
        b.cbranch(b.icmp_signed("<", i, self.full_end), body_bb, tail_bb)
        b.position_at_end(body_bb)
        every = const(self.mask_ty, 1)
        if mask == "all":
            um, exec_mask = None, every
        elif mask == "masked":
            um = exec_mask = self.load_user_mask(i, None, how)
        else:
            um = exec_mask = self.mem.branch(
                self.has_mask, lambda: self.load_user_mask(i, None, how), lambda: every)
        results = self.call_body(i, exec_mask, None, how)
        self.store_outs(i, results, um, how, self.has_mask if mask == "either" else None)
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
        um = b.and_(lanes, self.load_user_mask(full_end, lanes, "any"))
        with_m_end = b.block
        b.branch(join)
        b.position_at_end(join)
        exec_mask = b.phi(self.mask_ty)
        exec_mask.add_incoming(lanes, pre)
        exec_mask.add_incoming(um, with_m_end)
        results = self.call_body(full_end, exec_mask, lanes, "any")
        self.store_outs(full_end, results, exec_mask, "any")
        b.branch(done)


def _vector_groups(args: list[CArg], arrays: list[StridedArray | None]
                   ) -> dict[int, ArrayGroup]:
    """The arrays that are the 2, 3 or 4 components of one vector argument or result (named
    ``<path>.x``, ``<path>.y``, ...), by the position of the first."""
    groups: dict[int, ArrayGroup] = {}
    k = 0
    while k < len(args):
        head, end = args[k].name.rpartition(".")[0], k
        while end < len(args) and end - k < 4 and args[end].strided \
                and args[end].name == f"{head}.{'xyzw'[end - k]}" \
                and args[end].dtype == args[k].dtype:
            end += 1
        if end - k in SHUFFLE_FACTORS:
            groups[k] = ArrayGroup([a for a in arrays[k:end] if a is not None])
        k = max(end, k + 1)
    return groups
