"""LLVM lowering of the ray queries ``intersect`` (rdsl ``trace``) and ``occluded``.

Each query fills an Embree ``RTCRayHitN``/``RTCRayN`` packet on the stack from the lanes'
vector registers and calls ``rtcIntersectN``/``rtcOccludedN`` (N = the target's width) on
the scene stored in the library's global ``rdsl_embree_scene`` (set by the runtime before a
render).  One call per packet; no Python per ray.  Packet layouts come from
:mod:`rdsl.core.embree_abi`, their llvmlite types from :mod:`.embree_llvm`.
"""

from __future__ import annotations

import llvmlite.ir as L

from ...core.embree_abi import PacketLayout
from .. import ir
from . import embree_llvm as E
from .llvm_ops import F32, I32, PTR, Lowering, const

SCENE_GLOBAL = "rdsl_embree_scene"
INVALID_ID = -1  # RTC_INVALID_GEOMETRY_ID as i32


def uses_embree(module: ir.Module) -> bool:
    """Whether any kernel of ``module`` traces rays (its library must link libembree4)."""
    return any(ins.op in (ir.Op.INTERSECT, ir.Op.OCCLUDED)
               for fn in module.functions.values() for ins in fn.walk())


def _scene_global(lw: Lowering) -> L.GlobalVariable:
    mod = lw.m.mod
    if SCENE_GLOBAL in mod.globals:
        return mod.globals[SCENE_GLOBAL]
    g = L.GlobalVariable(mod, PTR, SCENE_GLOBAL)
    g.initializer = L.Constant(PTR, None)
    g.align = 8
    return g


def _entry_alloca(lw: Lowering, make) -> L.Value:
    """Run ``make(builder)`` at the top of the function's entry block (allocas there are
    reused by every loop iteration instead of growing the stack) and keep the main builder's
    insertion point valid."""
    entry = lw.fn.entry_basic_block
    eb = L.IRBuilder(entry)
    if entry.instructions:
        eb.position_before(entry.instructions[0])
    before = len(entry.instructions)
    slot = make(eb)
    if lw.b.block is entry:  # llvmlite builders track their position as an index
        lw.b._anchor += len(entry.instructions) - before
    return slot


def _lower_query(lw: Lowering, ins: ir.Instr) -> list[L.Value]:
    width = lw.m.width
    hit = ins.op is ir.Op.INTERSECT
    ops = [lw.v(o) for o in ins.operands]
    ox, oy, oz, dx, dy, dz, tmax = ops[:7]
    mask = ops[7] if len(ops) > 7 else None
    b = lw.b
    slot = _entry_alloca(lw, lambda eb: E.alloca_packet(eb, width, with_hit=hit))
    ety = E.llvm_rayhit_type(width) if hit else E.llvm_ray_type(width)
    packed = width > 1

    def field(name: str) -> L.Value:
        return b.gep(slot, E.field_indices(name, width, 0, with_hit=hit), source_etype=ety)

    def put(name: str, value: L.Value) -> None:
        b.store(value, field(name), align=4)

    def splat(ty: L.Type, v: float) -> L.Value:
        return const(L.VectorType(ty, width) if packed else ty, v)

    for name, v in (("org_x", ox), ("org_y", oy), ("org_z", oz), ("dir_x", dx),
                    ("dir_y", dy), ("dir_z", dz), ("tfar", tmax)):
        put(name, v)
    put("tnear", splat(F32, 0.0))
    put("time", splat(F32, 0.0))
    put("mask", splat(I32, -1))
    put("id", splat(I32, 0))
    put("flags", splat(I32, 0))
    if hit:
        put("geomID", splat(I32, INVALID_ID))
        put("instID", splat(I32, INVALID_ID))
    scene = b.load(_scene_global(lw), typ=PTR, align=8)
    fn = E.declare_query(lw.m.mod, "Intersect" if hit else "Occluded", width)
    null = L.Constant(PTR, None)
    if packed:
        vty = L.VectorType(I32, width)

        def make_valid(eb: L.IRBuilder) -> L.Value:
            v = eb.alloca(vty)
            v.align = PacketLayout(width, hit).align
            v.type = PTR  # opaque pointer, as everywhere in the backend
            return v

        valid = _entry_alloca(lw, make_valid)
        active = b.sext(mask, vty) if mask is not None else const(vty, -1)
        b.store(active, valid, align=4)
        b.call(fn, [valid, scene, slot, null])
    else:
        b.call(fn, [scene, slot, null])
    fty = L.VectorType(F32, width) if packed else F32
    ity = L.VectorType(I32, width) if packed else I32
    tfar = b.load(field("tfar"), typ=fty, align=4)
    if not hit:  # Embree sets tfar to -inf when the ray is occluded
        res = b.fcmp_ordered("==", tfar, const(fty, float("-inf")))
        return [b.and_(res, mask) if mask is not None else res]
    geom = b.load(field("geomID"), typ=ity, align=4)
    valid_hit = b.icmp_signed("!=", geom, const(ity, INVALID_ID))
    # a hit inside an instance: its geometry IDs start at the instance's own
    # (runtime/embree_instance.py), so mesh geomID of instance instID is instID + geomID
    inst = b.load(field("instID"), typ=ity, align=4)
    in_instance = b.icmp_signed("!=", inst, const(ity, INVALID_ID))
    geom = b.select(in_instance, b.add(inst, geom), geom)
    if mask is not None:
        valid_hit = b.and_(valid_hit, mask)
    return [tfar, b.load(field("u"), typ=fty, align=4), b.load(field("v"), typ=fty, align=4),
            b.load(field("primID"), typ=ity, align=4), geom, valid_hit]


RAY_LOWER = {ir.Op.INTERSECT: _lower_query, ir.Op.OCCLUDED: _lower_query}
