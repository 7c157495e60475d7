"""Gathers of a record: the fields of one element read as one 4-wide load per lane.

Kernels read records lane by lane at indices from memory: a vertex's ``P[3 * i + 0..2]``
(the index ``i`` from the triangle's ``F``), a triangle's ``F[3 * tri + 0..2]``, a
geometry record ``G[4 * g + 0..3]``, a uv ``UV[2 * i + 0..1]``.  Each field is a hardware
gather of its own (``vgatherdps``: on Zen 4 about 9 ns for 16 lanes), where one masked load
of the record's 4 elements per lane and a transpose (two rounds of unpacks) give every
field at once: measured on this project's Zen 4 host, 17 ns for the three fields of 16
vertices against 29 ns for three gathers (docs/bench.md, stop 40).

Contract: :func:`plan` groups the gathers of one IR block that read one buffer under one
mask at ``base + k`` for constants ``k`` within a window of 4 (``base`` the same value, or
the same product of a value and a constant in either operand order), where no instruction
between them writes memory (``store``, ``scatter``, ``call``, or a region holding one), and
only those whose i32 index comes from memory or is strided (``c * x`` plus uniform terms,
``|c| >= 2``: a texel's channels, a film pixel's); the others may walk an array lane by
lane and take the consecutive-run check of ``llvm_runs``.  Elements of 4 bytes, at 8 or
16 lanes on an x86 target with AVX2 or AVX-512.  :func:`emit` lowers a group where its
first member stands (which dominates the others: the operands of every member are defined
there) and returns each member's value: for an active lane the element the gather would
read, for an inactive lane 0, as the gather's pass-through.  Each lane's load is masked to
the fields the group reads, so it touches no element that a gather would not (no read past
a buffer's end), and an inactive lane reads a zeroed private constant instead of its own
address.  Values are bit for bit those of the gathers (tests/test_llvm_records.py,
tests/test_bit_identical.py).
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from .. import ir

I32 = L.IntType(32)
I64 = L.IntType(64)
WINDOW = 4  # elements per lane's load: one 128-bit row
_WRITES = frozenset({ir.Op.STORE, ir.Op.SCATTER, ir.Op.CALL})


class Group:
    """Gathers of one record: ``members`` (gather, offset) in program order."""

    __slots__ = ("members", "low", "values")

    def __init__(self, members: list[tuple[ir.Instr, int]]) -> None:
        self.members = members
        self.low = min(k for _, k in members)
        self.values: dict[int, L.Value] = {}  # offset -> the field's vector, once emitted


def enabled(target: Any, width: int) -> bool:
    """Whether the target has per-lane masked 128-bit loads and the lanes to transpose."""
    feats = getattr(target, "features", "")
    return (getattr(target, "backend", "") == "llvm" and width in (8, 16)
            and ("+avx2" in feats or "+avx512f" in feats))


def _const_int(v: ir.Value) -> int | None:
    """The constant a (broadcast of a) ``const`` i32 holds, else None."""
    o = v.owner
    if isinstance(o, ir.Instr) and o.op is ir.Op.BROADCAST and o.operands[0].type.lanes == 1:
        o = o.operands[0].owner
    if isinstance(o, ir.Instr) and o.op is ir.Op.CONST and not (o.attrs or {}).get("trait"):
        value = o.attrs.get("value")
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    return None


def split_index(idx: ir.Value) -> tuple[Any, int]:
    """``idx`` as (a key of its base, constant offset): ``x + k``, ``k + x``, ``x - k``."""
    offset = 0
    while True:
        o = idx.owner
        if not isinstance(o, ir.Instr) or o.op not in (ir.Op.ADD, ir.Op.SUB):
            break
        a, c = o.operands
        k = _const_int(c)
        if k is None and o.op is ir.Op.ADD:
            a, c = c, a
            k = _const_int(c)
        if k is None:
            break
        offset += k if o.op is ir.Op.ADD else -k
        idx = a
    o = idx.owner
    if isinstance(o, ir.Instr) and o.op is ir.Op.MUL:  # 3 * i and i * 3 alike
        x, y = o.operands
        kx, ky = _const_int(x), _const_int(y)
        if ky is not None or kx is not None:
            return ("mul", y if kx is not None else x, kx if kx is not None else ky), offset
    return ("value", idx), offset


def _uniform(v: ir.Value) -> bool:
    o = v.owner
    return isinstance(o, ir.Instr) and o.op is ir.Op.BROADCAST \
        and o.operands[0].type.lanes == 1


def _strided(base: Any) -> bool:
    """Whether a base from :func:`split_index` is ``c * x`` with ``|c| >= 2``, plus or minus
    uniform terms: two lanes' indices then differ by a multiple of ``c``, never by 1, so
    the consecutive-run check of ``llvm_runs`` could only succeed for a single active lane
    and is not worth its compare and branch."""
    if base[0] == "mul":
        return abs(base[2]) >= 2
    v = base[1]
    while True:
        o = v.owner
        if not isinstance(o, ir.Instr):
            return False
        if o.op is ir.Op.MUL:
            return any(abs(_const_int(x) or 0) >= 2 for x in o.operands)
        if o.op not in (ir.Op.ADD, ir.Op.SUB):
            return False
        a, c = o.operands
        if _uniform(c):
            v = a
        elif _uniform(a) and o.op is ir.Op.ADD:
            v = c
        else:
            return False


def _writes(ins: ir.Instr) -> bool:
    if ins.op in _WRITES:
        return True
    return bool(ins.regions) and any(i.op in _WRITES for r in ins.regions for i in r.walk())


def plan(lw: Any, blk: ir.Block) -> dict[ir.Instr, Group]:
    """The record groups of ``blk``'s own instructions, by member (see the contract)."""
    from .llvm_ops import MEM, _buf_elem

    open_: dict[Any, list[tuple[ir.Instr, int]]] = {}
    closed: list[list[tuple[ir.Instr, int]]] = []
    for ins in blk.instrs:
        if _writes(ins):
            closed.extend(open_.values())
            open_ = {}
            continue
        if ins.op is not ir.Op.GATHER:
            continue
        buf, idx, mask = ins.operands
        if idx.type.name != "i32" or MEM[_buf_elem(buf).name] not in (L.FloatType(), I32):
            continue
        base, k = split_index(idx)
        if not (lw.from_memory(idx) or _strided(base)):
            continue
        open_.setdefault((buf, base, mask), []).append((ins, k))
    closed.extend(open_.values())
    out: dict[ir.Instr, Group] = {}
    for members in closed:
        for window in _windows(members):
            group = Group(window)
            for ins, _ in window:
                out[ins] = group
    return out


def _windows(members: list[tuple[ir.Instr, int]]) -> list[list[tuple[ir.Instr, int]]]:
    """``members`` cut into windows of offsets ``low .. low + 3``, each of 2 fields or more
    (a single field stays a gather)."""
    offsets = sorted({k for _, k in members})
    out = []
    while offsets:
        low = offsets[0]
        inside = {k for k in offsets if k < low + WINDOW}
        offsets = [k for k in offsets if k >= low + WINDOW]
        if len(inside) >= 2:
            out.append([(i, k) for i, k in members if k in inside])
    return out


def _shuffle(b: L.IRBuilder, x: L.Value, y: L.Value, mask: list[int]) -> L.Value:
    return b.shuffle_vector(x, y, L.Constant(L.VectorType(I32, len(mask)),
                                             [L.Constant(I32, i) for i in mask]))


def _zero_row(lw: Any, ty: L.Type) -> L.Value:
    """A private zeroed row that inactive lanes read (one per element type and module)."""
    name = f"rdsl.zero_row.{'f32' if isinstance(ty, L.FloatType) else 'i32'}"
    g = lw.m.mod.globals.get(name)
    if g is None:
        g = L.GlobalVariable(lw.m.mod, L.ArrayType(ty, WINDOW), name)
        g.linkage = "internal"
        g.global_constant = True
        g.initializer = L.Constant(L.ArrayType(ty, WINDOW), None)
        g.align = 16
    return g


def emit(lw: Any, group: Group, first: ir.Instr, first_offset: int) -> None:
    """Lower ``group`` at its first member ``first`` (offset ``first_offset``): fill
    ``group.values`` with each field's vector of W lanes."""
    from .llvm_ops import MEM, _buf_elem, _gep, mangle

    b = lw.b
    buf, idx, mask = first.operands
    ty = MEM[_buf_elem(buf).name]
    m = lw.v(mask)
    W = m.type.count
    wide = lw.index64(idx)
    if first_offset != group.low:  # the record's first field this group reads
        wide = b.add(wide, lw.m.splat(b, L.Constant(I64, group.low - first_offset), W))
    ptrs = _gep(lw, lw.v(buf), wide, ty)
    safe = b.select(m, ptrs, lw.m.splat(b, _zero_row(lw, ty), W))
    fields = {k - group.low for _, k in group.members}
    row_ty = L.VectorType(ty, WINDOW)
    row_mask = L.Constant(L.VectorType(L.IntType(1), WINDOW),
                          [L.Constant(L.IntType(1), int(f in fields)) for f in range(WINDOW)])
    load = f"llvm.masked.load.{mangle(row_ty)}.p0"
    rows = [lw.call(load, row_ty, b.extract_element(safe, L.Constant(I32, lane)),
                    L.Constant(I32, 4), row_mask, L.Constant(row_ty, None))
            for lane in range(W)]
    blocks = W // WINDOW
    # r[q]'s 128-bit block j holds the row of lane q + 4j
    r = []
    for q in range(WINDOW):
        parts = [rows[q + WINDOW * j] for j in range(blocks)]
        while len(parts) > 1:
            n = parts[0].type.count
            parts = [_shuffle(b, parts[i], parts[i + 1], list(range(2 * n)))
                     for i in range(0, len(parts), 2)]
        r.append(parts[0])

    def unpack(x: L.Value, y: L.Value, picks: tuple[int, int, int, int]) -> L.Value:
        # per 128-bit block j: (x|y)[4j + pick], y's elements numbered from W
        return _shuffle(b, x, y, [4 * j + p for j in range(blocks) for p in picks])

    lo = (0, W, 1, W + 1)      # unpcklps
    hi = (2, W + 2, 3, W + 3)  # unpckhps
    pairs = {0: (lo, (0, 1, W, W + 1)), 1: (lo, (2, 3, W + 2, W + 3)),
             2: (hi, (0, 1, W, W + 1)), 3: (hi, (2, 3, W + 2, W + 3))}
    halves: dict[tuple[int, ...], tuple[L.Value, L.Value]] = {}
    for f in sorted(fields):
        first_round, second_round = pairs[f]
        if first_round not in halves:
            halves[first_round] = (unpack(r[0], r[1], first_round),
                                   unpack(r[2], r[3], first_round))
        t, u = halves[first_round]
        group.values[f + group.low] = unpack(t, u, second_round)
