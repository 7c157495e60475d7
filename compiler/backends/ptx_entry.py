"""The CUDA entry point of a kernel, in LLVM for the NVPTX backend.

A module built for target ``ptx`` is vectorized at width 1: one CUDA thread is one lane.  Each
exported kernel becomes a ``ptx_kernel`` function with the C ABI's arguments (see
:func:`rdsl.compiler.backends.base.c_params`), buffers and arrays as pointers to global
memory::

    rdsl_<name>(i64 n, args..., outs..., ptr mask, i64 mask_stride)

It runs a grid-stride loop: thread ``ctaid.x * ntid.x + tid.x`` takes elements ``i``,
``i + nctaid.x * ntid.x``, ... below ``n``, so any launch size covers every element.  Element
``i`` of an array is at ``base + i * stride`` (bytes), as on the CPU.  A null mask means every
element is active; an element whose mask byte is 0 is skipped and its outputs are left as
they were (the CPU entry's contract).  The body is the LLVM backend's (``llvm.py``), the same
function the CPU entry points call, always inlined.

What PTX cannot run is refused here, before LLVM sees it: the ray queries ``intersect`` and
``occluded`` call Embree, a CPU library; a render kernel for a GPU traces rays with the BVH
in rdsl (``accel="bvh"``), which removes them before code generation.
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir
from ..diagnostics import CompileError
from .base import c_arg_names, c_args, c_name, split_params
from .llvm_ops import ALIGN, I1, I8, I32, I64, MEM, PTR, const

GLOBAL = L.PointerType(addrspace=1)  # CUDA global memory
SREG = "llvm.nvvm.read.ptx.sreg."
_RAY_OPS = {ir.Op.INTERSECT: "trace", ir.Op.OCCLUDED: "occluded"}


def check_ptx_module(module: ir.Module) -> None:
    """Refuse what the NVPTX backend cannot lower: a width other than 1, a ray query."""
    width = int(module.attrs.get("width", 1))
    if width != 1:
        raise CompileError(f"target ptx runs one lane per CUDA thread: the module was "
                           f"vectorized for width {width}, not 1")
    for fn in module.functions.values():
        for ins in fn.walk():
            name = _RAY_OPS.get(ins.op)
            if name is not None:
                raise CompileError(
                    f"target ptx cannot lower the ray query `{name}` (`{ins.op.value}`): it "
                    "calls Embree, which runs on the CPU only; trace rays on the GPU with "
                    "the BVH in rdsl (`--accel bvh`)", ins.loc)


def emit_ptx_kernel(ml: Any, fn: ir.Function, body: L.Function) -> None:
    """Emit the ``ptx_kernel`` entry ``rdsl_<name>`` of kernel ``fn`` whose lowered body is
    ``body``; ``ml`` is the LLVM module lowering (``llvm._ModuleLowering``)."""
    _, mask_param = split_params(fn)
    if mask_param is None:
        raise CompileError(f"kernel `{fn.name}` has no execution mask parameter "
                           "(run vectorize first)", fn.loc)
    args = c_args(fn)
    tys: list[L.Type] = [I64]
    for a in args:
        tys.append(GLOBAL if a.kind != "uniform" else MEM[a.dtype])
        if a.strided:
            tys.append(I64)
    tys += [GLOBAL, I64]
    entry = L.Function(ml.mod, L.FunctionType(L.VoidType(), tys), "rdsl_" + c_name(fn.name))
    entry.calling_convention = "ptx_kernel"
    ml.attrs(entry)
    _EntryBuilder(ml, entry, body, args).emit()


class _EntryBuilder:
    """The grid-stride loop of one entry: names its arguments, loads lane ``i`` of each
    varying input, calls the body, stores its results."""

    def __init__(self, ml: Any, entry: L.Function, body: L.Function, args: list) -> None:
        self.ml, self.fn, self.body, self.args = ml, entry, body, args
        self.b = L.IRBuilder(entry.append_basic_block("entry"))
        it = iter(entry.args)
        self.n = next(it)
        self.n.name = "n"
        self.vals: list[tuple[L.Value, L.Value | None]] = []  # (value or base, stride)
        for a, name in zip(args, c_arg_names(args)):
            v = next(it)
            v.name = name
            stride = None
            if a.strided:
                stride = next(it)
                stride.name = name + "_stride"
            self.vals.append((v, stride))
        self.mask, self.mask_stride = next(it), next(it)
        self.mask.name, self.mask_stride.name = "mask", "mask_stride"

    def sreg(self, name: str) -> L.Value:
        f = self.ml.intrinsic(SREG + name, I32, [])
        return self.b.zext(self.b.call(f, []), I64)

    def element(self, base: L.Value, stride: L.Value, i: L.Value) -> L.Value:
        """The generic address of element ``i`` of a strided array in global memory."""
        p = self.b.gep(base, [self.b.mul(i, stride)], source_etype=I8)
        return self.b.addrspacecast(p, PTR)

    def emit(self) -> None:
        b = self.b
        start = b.add(b.mul(self.sreg("ctaid.x"), self.sreg("ntid.x")), self.sreg("tid.x"))
        step = b.mul(self.sreg("nctaid.x"), self.sreg("ntid.x"))
        # uniform bools and buffers are converted once, outside the loop
        ins = []
        for a, (v, _) in zip(self.args, self.vals):
            if a.kind == "uniform" and a.dtype == "bool":
                v = b.icmp_unsigned("!=", v, const(I8, 0))
            elif a.kind == "buffer":
                v = b.addrspacecast(v, PTR)
            ins.append(v)
        has_mask = b.icmp_unsigned("!=", self.mask, L.Constant(GLOBAL, None))
        pre = b.block
        head = self.fn.append_basic_block("loop")
        work = self.fn.append_basic_block("lane")
        active = self.fn.append_basic_block("active")
        latch = self.fn.append_basic_block("next")
        done = self.fn.append_basic_block("done")
        b.branch(head)
        b.position_at_end(head)
        i = b.phi(I64, name="i")
        i.add_incoming(start, pre)
        b.cbranch(b.icmp_signed("<", i, self.n), work, done)
        b.position_at_end(work)
        with b.if_then(has_mask):  # load the mask byte only where a mask was given
            m = b.load(self.element(self.mask, self.mask_stride, i), typ=I8)
            m = b.icmp_unsigned("!=", m, const(I8, 0))
            masked_bb = b.block
        on = b.phi(I1)
        on.add_incoming(const(I1, 1), work)
        on.add_incoming(m, masked_bb)
        b.cbranch(on, active, latch)
        b.position_at_end(active)
        self.lane(i, ins)
        b.branch(latch)
        b.position_at_end(latch)
        i.add_incoming(b.add(i, step), latch)
        b.branch(head)
        b.position_at_end(done)
        b.ret_void()

    def lane(self, i: L.Value, ins: list[L.Value]) -> None:
        """Element ``i``: load the varying inputs, call the body, store the outputs."""
        b = self.b
        call_args = []
        outs = []
        for a, (v, stride), u in zip(self.args, self.vals, ins):
            if a.kind == "varying":
                x = b.load(self.element(v, stride, i), typ=MEM[a.dtype], align=ALIGN[a.dtype])
                if a.dtype == "bool":
                    x = b.icmp_unsigned("!=", x, const(I8, 0))
                call_args.append(x)
            elif a.kind == "output":
                outs.append((a, self.element(v, stride, i)))
            else:
                call_args.append(u)
        res = b.call(self.body, call_args + [const(I1, 1)])
        for k, (a, p) in enumerate(outs):
            r = b.extract_value(res, k)
            if a.dtype == "bool":
                r = b.zext(r, I8)
            b.store(r, p, align=ALIGN[a.dtype])
