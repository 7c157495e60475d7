"""The LLVM CPU backend: post-vectorize IR -> llvmlite IR -> optimized LLVM IR, asm, objects.

Each exported kernel becomes

* an internal ``alwaysinline`` body function taking the kernel's params as LLVM values
  (varying ``f32`` -> ``<W x float>``, ``bool`` -> ``<W x i1>``, buffers -> ``ptr``) and
  returning a literal struct of its results, and
* two C entry points (see :func:`rdsl.compiler.backends.base.c_prototype`):
  ``rdsl_<name>_range(begin, end, args..., outs..., mask)`` which loops over ``[begin, end)``
  in steps of W (full vectors with plain loads and stores, the tail with masked ones), and
  ``rdsl_<name>(n, ...)`` which calls it on ``[0, n)``.

Instructions are lowered through ``llvm_ops.LOWER``, a dispatch table keyed by
:class:`ir.Op`; the entry points are built by ``llvm_entry``.  The semantics are those of
``docs/ir.md``, bit for bit: no fast-math, no FMA contraction.
"""

from __future__ import annotations

import llvmlite.ir as L

from .. import ir
from ..diagnostics import CompileError
from ..targets import Target, get_target
from .base import Backend, c_name, kernels, result_names
from .llvm_entry import emit_kernel
from .llvm_ops import I32, LOWER, Lowering, const, ll_type
from .llvm_records import enabled as records_enabled
from .llvm_rays import RAY_LOWER

LOWER.update(RAY_LOWER)  # ray queries (Embree) are lowered in their own file


class LLVMBackend(Backend):
    """x86-64 CPU code through LLVM (scalar, SSE4, AVX2, AVX-512)."""

    name = "llvm"
    emits = ("llvm", "asm", "obj")
    supports_gather = True
    supports_scatter = True
    supports_float_rem = True
    max_width = 16
    widths = (1, 4, 8, 16)


# --------------------------------------------------------------------------------------
# Module lowering: body functions and C entry points


class _ModuleLowering:
    """Lowers a module: one body function plus C entry points per kernel."""

    def __init__(self, module: ir.Module, target: Target, records: bool = True) -> None:
        self.ir = module
        self.target = target
        self.width = LLVMBackend().check_module(module)
        if self.width != target.width:
            raise CompileError(f"module was vectorized for width {self.width} but target "
                               f"`{target.name}` has width {target.width}")
        self.mod = L.Module(name=module.attrs.get("name", "rdsl"))
        self.mod.triple = target.triple
        self.records = records and records_enabled(target, self.width)
        self._intrinsics: dict[str, L.Function] = {}
        self.entry = emit_kernel  # the entry points around each body: C, or CUDA's
        self.rules = LOWER  # the lowering rule of each op (llvm_ops)
        if target.backend == "ptx":
            from .ptx_entry import check_ptx_module, emit_ptx_kernel
            from .ptx_ops import PTX_LOWER

            check_ptx_module(module)
            self.entry = emit_ptx_kernel
            self.rules = {**LOWER, **PTX_LOWER}

    # -- small utilities -----------------------------------------------------------------
    def intrinsic(self, name: str, ret: L.Type, args: list[L.Type]) -> L.Function:
        fn = self._intrinsics.get(name)
        if fn is None:
            fn = L.Function(self.mod, L.FunctionType(ret, args), name)
            self._intrinsics[name] = fn
        return fn

    def attrs(self, fn: L.Function) -> None:
        t = self.target
        for a in (f'"target-cpu"="{t.cpu}"', f'"target-features"="{t.features}"',
                  f'"min-legal-vector-width"="{t.vector_bits}"',
                  f'"prefer-vector-width"="{t.vector_bits}"', "nounwind"):
            set.add(fn.attributes, a)  # llvmlite only knows enum attributes

    def splat(self, b: L.IRBuilder, v: L.Value, n: int) -> L.Value:
        vty = L.VectorType(v.type, n)
        ins = b.insert_element(L.Constant(vty, None), v, const(I32, 0))
        return b.shuffle_vector(ins, L.Constant(vty, None), const(L.VectorType(I32, n), 0))

    def guarded_load(self, b: L.IRBuilder, p: L.Value, ty: L.Type, align: int,
                     m: L.Value) -> L.Value:
        pre = b.block
        with b.if_then(m):
            loaded = b.load(p, typ=ty, align=align)
            inner = b.block
        phi = b.phi(ty)
        phi.add_incoming(const(ty, 0), pre)
        phi.add_incoming(loaded, inner)
        return phi

    # -- kernels -----------------------------------------------------------------------
    def run(self) -> L.Module:
        seen: dict[str, str] = {}
        for fn in kernels(self.ir):
            other = seen.setdefault(c_name(fn.name), fn.name)
            if other != fn.name:
                raise CompileError(f"kernels `{other}` and `{fn.name}` both export the C "
                                   f"symbol rdsl_{c_name(fn.name)}", fn.loc)
            self.entry(self, fn, self.body(fn))
        return self.mod

    def body(self, fn: ir.Function) -> L.Function:
        params = [ll_type(p.value.type) for p in fn.params]
        rty = L.LiteralStructType([ll_type(t) for t in fn.ret_types])
        f = L.Function(self.mod, L.FunctionType(rty, params), f"rdsl.body.{c_name(fn.name)}")
        f.linkage = "internal"
        # A small body is inlined into each of the range function's four loops (contiguous,
        # user mask, strided, tail), where its loads and stores fuse with it; a large one is
        # called from them instead: four copies of a BSDF's or a path tracer's body made
        # LLVM's optimization and codegen four times as long, for a call per W lanes that
        # costs nothing next to such a body.
        # (CUDA's entry has one loop, and a call would pass the body's results on the stack.)
        size = sum(1 for _ in fn.walk())
        small = size <= INLINE_BODY_LIMIT or self.entry is not emit_kernel
        f.attributes.add("alwaysinline" if small else "noinline")
        self.attrs(f)
        lw = Lowering(self, f)
        for p, arg in zip(fn.params, f.args):
            lw.vals[p.value] = arg
        lw.block(fn.body)
        if not lw.b.block.is_terminated:
            raise CompileError(f"kernel `{fn.name}` does not end in `return`", fn.loc)
        return f

# --------------------------------------------------------------------------------------
# Public API


def lower_module(module: ir.Module, target: Target | str, quick: bool = False) -> L.Module:
    """The unoptimized llvmlite module for ``module``.  ``quick`` (the quick tier): no
    record loads (llvm_records), whose per-lane loads and shuffles cost the quick tier
    more compile time than the kernel they speed up runs at O0."""
    return _ModuleLowering(module, get_target(target), records=not quick).run()


def release_module(lowered: L.Module) -> None:
    """Cut the cycles of an llvmlite module that has been printed (an instruction's
    ``parent`` is its block, which lists it; a phi's incoming values lead back to it), so
    that reference counting frees it at once: left to Python's cycle collector, the
    collection after a compile took 0.1-0.2 s of a kernel's 1-3 s (the module is the largest
    object graph a compile makes).  ``lowered`` is empty afterwards."""
    for fn in list(lowered.functions):
        for block in fn.blocks:
            for ins in block.instructions:
                ins.operands, ins.parent = [], None
                if isinstance(ins, L.PhiInstr):
                    ins.incomings = []
            block.instructions, block.parent, block.terminator = [], None, None
        fn.blocks, fn.args, fn.parent, fn.return_value = [], (), None, None
    lowered.globals.clear()


# Bodies of more IR instructions than this are called, not inlined, by their range loops
# (see _ModuleLowering.body): 13% less CPU time to compile a large BSDF's test harness.
INLINE_BODY_LIMIT = 1500


def _binding(all_targets: bool = False):
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    if all_targets:  # NVPTX
        llvm.initialize_all_targets()
        llvm.initialize_all_asmprinters()
    return llvm


def target_machine(target: Target | str, quick: bool = False):
    """An llvmlite TargetMachine for ``target`` (position independent, O3; ``quick``: O0,
    LLVM's fast instruction selection)."""
    t = get_target(target)
    llvm = _binding(t.backend != "llvm")
    tgt = llvm.Target.from_triple(t.triple)
    return tgt.create_target_machine(cpu=t.cpu, features=t.features, opt=0 if quick else 3,
                                     reloc="pic" if t.backend == "llvm" else "default",
                                     codemodel="default")


def optimized_module(module: ir.Module, target: Target | str, speed: int = 3,
                     quick: bool = False):
    """Lower, verify and optimize with LLVM's O``speed`` pipeline (O3 for kernels; the
    run-once table kernels of compiler/precompute.py take less); return the binding
    ModuleRef and the target machine.  ``quick``: the quick tier, O0 and fast instruction
    selection (see :func:`emit_object`)."""
    t = get_target(target)
    llvm = _binding()
    lowered = lower_module(module, t, quick)
    text = str(lowered)
    release_module(lowered)
    try:
        mod = llvm.parse_assembly(text)
        mod.verify()
    except RuntimeError as e:  # an internal error: show the IR we produced
        raise CompileError(f"internal error: the LLVM backend produced invalid IR: {e}\n"
                           + text) from None
    tm = target_machine(t, quick)
    mod.triple = t.triple
    mod.data_layout = str(tm.target_data)
    pto = llvm.PipelineTuningOptions(speed_level=0 if quick else speed)
    # our vectorization is explicit: keep LLVM from re-vectorizing the lane loops (and keep
    # the scalar target scalar, so that speedups measure our vectorizer)
    pto.loop_vectorization = False
    pto.slp_vectorization = t.width > 1
    pb = llvm.create_pass_builder(tm, pto)
    pb.getModulePassManager().run(mod, pb)
    return mod, tm


def emit_llvm(module: ir.Module, target: Target | str = "host") -> str:
    """Optimized textual LLVM IR."""
    mod, _ = optimized_module(module, target)
    return str(mod)


def emit_asm(module: ir.Module, target: Target | str = "host") -> str:
    """Assembly for ``target``."""
    mod, tm = optimized_module(module, target)
    return tm.emit_assembly(mod)


def emit_object(module: ir.Module, target: Target | str = "host", quick: bool = False
                ) -> bytes:
    """An ELF object file for ``target``.  ``quick``: the quick tier, LLVM's O0 pipeline and
    fast instruction selection.  The IR arrives optimized by rdsl's own passes, so this
    compiles in about 60% of the time of O3 and the kernels run 15-30% slower, with results
    bit for bit the same (neither tier uses fast-math): docs/bench.md."""
    mod, tm = optimized_module(module, target, quick=quick)
    return tm.emit_object(mod)


def kernel_signatures(module: ir.Module) -> dict[str, str]:
    """Kernel name -> C prototype of its ``rdsl_<name>`` entry point."""
    from .base import c_prototype

    return {fn.name: c_prototype(fn) for fn in kernels(module)}


__all__ = [
    "LLVMBackend",
    "emit_asm",
    "emit_llvm",
    "emit_object",
    "kernel_signatures",
    "ll_type",
    "lower_module",
    "result_names",
]
