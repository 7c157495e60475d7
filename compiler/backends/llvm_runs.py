"""Whether the lanes' indices of a gather or scatter are consecutive, checked at run time,
once per index: the LLVM backend's masked vector access instead of W scattered ones.

A gather whose lanes turn out to read consecutive elements (``idx[k] == first + k``) is
one masked vector load (``llvm_ops._gather_or_load``; scatters likewise).  The check costs
a handful of instructions, and kernels read many arrays at offsets of one index: the
film's planes ``S[(c + dx) * ns + i]`` (five per tap), a sample's row of the adjoint's
tape ``ad_row_tape + j * 16`` (every carried value of a bounce).  An index ``x + u`` or
``x - u`` (``u`` uniform, broadcast) is consecutive exactly when ``x`` is, with ``first``
shifted by ``u`` (in i32's wrapping arithmetic both ways), so :func:`consecutive_run`
checks ``x`` once per execution mask and reuses the check for every offset of it, in the
IR block where it was made and the blocks nested in it (which it dominates;
``Lowering.block`` scopes it).
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir

I32 = L.IntType(32)


def _base_and_offset(lw: Any, idx: ir.Value) -> tuple[ir.Value, L.Value | None]:
    """``idx`` as ``base + offset``: ``base`` varying, ``offset`` the sum (an LLVM i32
    scalar, or None for 0) of the uniform terms added to it (or subtracted: ``x - u``)."""
    offset = None
    while True:
        ins = idx.owner
        if not isinstance(ins, ir.Instr) or ins.op not in (ir.Op.ADD, ir.Op.SUB):
            return idx, offset
        pairs = [ins.operands] if ins.op is ir.Op.SUB else \
            [ins.operands, ins.operands[::-1]]
        for x, u in pairs:
            o = u.owner
            if isinstance(o, ir.Instr) and o.op is ir.Op.BROADCAST \
                    and o.operands[0].type.lanes == 1:
                s = lw.v(o.operands[0])
                if ins.op is ir.Op.SUB:
                    s = lw.b.neg(s)
                offset = s if offset is None else lw.b.add(offset, s)
                idx = x
                break
        else:
            return idx, offset


def consecutive_run(lw: Any, idx: ir.Value, mask: L.Value) -> tuple[L.Value, L.Value]:
    """The index lane 0 would have, ``first``, and whether every active lane k of ``mask``
    has ``idx[k] == first + k`` (i32 indices): then a masked vector access at ``first``
    touches exactly the active lanes' elements (see the module's docstring for the reuse)."""
    base, offset = _base_and_offset(lw, idx)
    key = (base, id(mask))  # the entry holds the mask too, so its id is not reused
    if key not in lw.runs:
        lw.runs[key] = (*_consecutive(lw, lw.v(base), mask.type.count, mask), mask)
    first, ok, _ = lw.runs[key]
    return (first if offset is None else lw.b.add(first, offset)), ok


def _consecutive(lw: Any, idx: L.Value, W: int, mask: L.Value) -> tuple[L.Value, L.Value]:
    """``first`` and the check for the LLVM vector ``idx``.  Inactive lanes are not
    compared, so a packet whose finished lanes kept stale indices (a loop's lanes leave it
    at different iterations: the adjoint's tape slots) still takes the vector access;
    ``first`` comes from the first active lane (any value when none is: nothing is
    accessed then)."""
    b = lw.b
    iota = L.Constant(L.VectorType(I32, W), [L.Constant(I32, k) for k in range(W)])
    bits_ty = L.IntType(W)  # W <= 16: a lane mask's bits fit an i32
    active = b.zext(b.bitcast(mask, bits_ty), I32)
    lead = lw.call("llvm.cttz.i32", I32, active, L.Constant(L.IntType(1), 0))
    lane = b.and_(lead, L.Constant(I32, W - 1))  # 32 (no lane active) -> lane 0
    first = b.sub(b.extract_element(idx, lane), lane)
    same = b.icmp_signed("==", idx, b.add(lw.m.splat(b, first, W), iota))
    bits = b.bitcast(b.or_(same, b.not_(mask)), bits_ty)
    return first, b.icmp_signed("==", bits, L.Constant(bits_ty, -1))


__all__ = ["consecutive_run"]
