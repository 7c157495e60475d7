"""Lowering rules the ptx target replaces: float ``rem``.

The IR's float ``rem`` is C's ``fmodf``: exact (the remainder of two floats is always a
float).  LLVM's NVPTX backend expands ``frem`` into ``x - trunc(x / y) * y``, which is not
(the quotient rounds once ``x / y`` passes 2^24), and libdevice's ``fmodf`` is not available
through llvmlite.  So the ptx target calls :func:`define_fmodf`: musl's integer ``fmodf``
(long division on the significands, one bit per step), spelled in LLVM IR.  It uses integer
operations, shifts and ``ctlz`` only, so it computes the same bits on every LLVM target; the
tests run the same function on the CPU against numpy's ``fmod``.
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir
from .llvm_ops import F32, I1, I32, LOWER, const

FMODF = "rdsl.fmodf"


def define_fmodf(mod: L.Module) -> L.Function:
    """``float rdsl.fmodf(float x, float y)`` in ``mod`` (defined once): C's ``fmodf``."""
    if FMODF in mod.globals:
        return mod.globals[FMODF]
    fn = L.Function(mod, L.FunctionType(F32, [F32, F32]), FMODF)
    fn.linkage = "internal"
    x, y = fn.args
    b = L.IRBuilder(fn.append_basic_block("entry"))
    ctlz = L.Function(mod, L.FunctionType(I32, [I32, I1]), "llvm.ctlz.i32") \
        if "llvm.ctlz.i32" not in mod.globals else mod.globals["llvm.ctlz.i32"]
    c = lambda v: const(I32, v)
    ux, uy = b.bitcast(x, I32), b.bitcast(y, I32)
    ex, ey = (b.and_(b.lshr(u, c(23)), c(0xFF)) for u in (ux, uy))
    sx = b.and_(ux, c(-0x80000000))
    ux2, uy2 = b.shl(ux, c(1)), b.shl(uy, c(1))
    zero = b.fmul(const(F32, 0.0), x)

    def leave(cond: L.Value, value: L.Value) -> None:
        """Return ``value`` when ``cond`` holds; go on in a new block otherwise."""
        out, on = fn.append_basic_block("ret"), fn.append_basic_block("on")
        b.cbranch(cond, out, on)
        b.position_at_end(out)
        b.ret(value)
        b.position_at_end(on)

    nan = b.or_(b.or_(b.icmp_unsigned("==", uy2, c(0)), b.fcmp_unordered("uno", y, y)),
                b.icmp_unsigned("==", ex, c(0xFF)))
    xy = b.fmul(x, y)
    leave(nan, b.fdiv(xy, xy))
    leave(b.icmp_unsigned("<", ux2, uy2), x)  # |x| < |y|
    leave(b.icmp_unsigned("==", ux2, uy2), zero)

    def normalize(u: L.Value, e: L.Value) -> tuple[L.Value, L.Value]:
        """The significand with its leading 1 at bit 23, and the (unbiased for subnormals)
        exponent."""
        lz = b.call(ctlz, [b.shl(u, c(9)), const(I1, 0)])
        sub = b.icmp_unsigned("==", e, c(0))
        u_sub, e_sub = b.shl(u, b.add(lz, c(1))), b.sub(c(0), lz)
        u_norm = b.or_(b.and_(u, c(0x7FFFFF)), c(0x800000))
        return b.select(sub, u_sub, u_norm), b.select(sub, e_sub, e)

    mx, ex = normalize(ux, ex)
    my, ey = normalize(uy, ey)
    pre = b.block
    head, body, tail = (fn.append_basic_block(n) for n in ("loop", "step", "last"))
    b.branch(head)
    b.position_at_end(head)
    m, e = b.phi(I32), b.phi(I32)
    m.add_incoming(mx, pre)
    e.add_incoming(ex, pre)
    b.cbranch(b.icmp_signed(">", e, ey), body, tail)
    b.position_at_end(body)  # one bit of the quotient: subtract where it fits, shift
    i = b.sub(m, my)
    fits = b.icmp_signed(">=", i, c(0))
    leave(b.icmp_signed("==", i, c(0)), zero)
    step_end = b.block
    m.add_incoming(b.shl(b.select(fits, i, m), c(1)), step_end)
    e.add_incoming(b.sub(e, c(1)), step_end)
    b.branch(head)
    b.position_at_end(tail)
    i = b.sub(m, my)
    leave(b.icmp_signed("==", i, c(0)), zero)
    r = b.select(b.icmp_signed(">=", i, c(0)), i, m)
    shift = b.sub(b.call(ctlz, [r, const(I1, 0)]), c(8))  # leading 1 back to bit 23
    r, e = b.shl(r, shift), b.sub(e, shift)
    normal = b.or_(b.sub(r, c(0x800000)), b.shl(e, c(23)))
    subnormal = b.lshr(r, b.sub(c(1), e))
    bits = b.or_(b.select(b.icmp_signed(">", e, c(0)), normal, subnormal), sx)
    b.ret(b.bitcast(bits, F32))
    return fn


def _lower_rem(lw: Any, ins: ir.Instr) -> L.Value:
    t = lw.elem(ins)
    if not t.is_float:
        return LOWER[ir.Op.REM](lw, ins)
    a, b = (lw.v(o) for o in ins.operands)
    return lw.b.call(define_fmodf(lw.m.mod), [a, b])


PTX_LOWER = {ir.Op.REM: _lower_rem}
