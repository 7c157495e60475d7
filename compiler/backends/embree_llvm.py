"""Embree's ray packets and query functions as llvmlite types and declarations.

:func:`llvm_rayhit_type`, :func:`llvm_ray_type` and :func:`declare_query` describe the
``RTCRayHitN``/``RTCRayN`` structs and the ``rtcIntersectN``/``rtcOccludedN`` functions to
llvmlite, with the exact layout of ``embree4/rtcore_ray.h`` (:mod:`rdsl.core.embree_abi`
gives the fields and :class:`~rdsl.core.embree_abi.PacketLayout` the sizes these types must
have); :func:`alloca_packet` and :func:`field_indices` allocate a packet and address its
fields.  ``llvm_rays.py`` lowers the ``trace`` and ``occluded`` queries with them.
"""

from __future__ import annotations

from typing import Any

import llvmlite.ir as L

from ...core.embree_abi import (
    HIT_FIELDS,
    INSTANCE_FIELDS,
    QUERIES,
    RAY_FIELDS,
    UINT_FIELDS,
    PacketLayout,
    check_width,
)


def llvm_ray_type(width: int) -> L.LiteralStructType:
    """The llvmlite type of ``RTCRay`` (width 1) or ``RTCRay{4,8,16}``.

    A literal struct of the 12 ray fields in header order: scalars for width 1, else
    ``[width x float|i32]`` rows. Allocate it with :data:`alignment` ``PacketLayout(w).align``
    (see :func:`alloca_packet`)."""
    check_width(width)
    f32, i32 = L.FloatType(), L.IntType(32)

    def row(field: str) -> L.Type:
        base = i32 if field in UINT_FIELDS else f32
        return base if width == 1 else L.ArrayType(base, width)

    return L.LiteralStructType([row(f) for f in RAY_FIELDS])


def llvm_hit_type(width: int) -> L.LiteralStructType:
    """The llvmlite type of ``RTCHit`` or ``RTCHit{4,8,16}`` (see :func:`llvm_rayhit_type`).

    Fields in header order; ``instID`` and ``instPrimID`` are ``[1 x ...]`` arrays (one
    instance level). The single-ray hit carries 3 trailing words of padding to 48 bytes."""
    check_width(width)
    f32, i32 = L.FloatType(), L.IntType(32)
    fields: list[L.Type] = []
    for field in HIT_FIELDS:
        base = i32 if field in UINT_FIELDS else f32
        t = base if width == 1 else L.ArrayType(base, width)
        fields.append(L.ArrayType(t, 1) if field in INSTANCE_FIELDS else t)
    lay = PacketLayout(width)
    pad = lay.words - lay.ray_words - len(HIT_FIELDS) * width
    if pad:
        fields.append(L.ArrayType(i32, pad))
    return L.LiteralStructType(fields)


def llvm_rayhit_type(width: int) -> L.LiteralStructType:
    """The llvmlite type of ``RTCRayHit`` / ``RTCRayHit{4,8,16}``: ``{ray, hit}``.

    Its size is ``PacketLayout(width).nbytes`` (96, 336, 672, 1344 bytes); field
    ``RAY_FIELDS[j]`` is at GEP indices ``(0, 0, j)``, ``HIT_FIELDS[j]`` at ``(0, 1, j)``,
    then ``lane`` for packets (and ``0`` before it for the instance-level arrays)."""
    return L.LiteralStructType([llvm_ray_type(width), llvm_hit_type(width)])


def field_indices(field: str, width: int, lane: int | Any = 0, *,
                  with_hit: bool = True) -> list[Any]:
    """GEP indices (i32 constants, or ``lane`` as given) of one lane of ``field``."""
    i32 = L.IntType(32)

    def c(k: int) -> L.Constant:
        return L.Constant(i32, k)

    lane_v = c(lane) if isinstance(lane, int) else lane
    if field in RAY_FIELDS:
        path = [c(0), c(0), c(RAY_FIELDS.index(field))] if with_hit else \
               [c(0), c(RAY_FIELDS.index(field))]
    elif with_hit and field in HIT_FIELDS:
        path = [c(0), c(1), c(HIT_FIELDS.index(field))]
        if field in INSTANCE_FIELDS:
            path.append(c(0))
    else:
        raise KeyError(f"no field {field!r}")
    return path if width == 1 else path + [lane_v]


def alloca_packet(builder: L.IRBuilder, width: int, *, with_hit: bool = True,
                  name: str = "") -> L.AllocaInstr:
    """An ``alloca`` of ``RTCRayHitN`` (or ``RTCRayN``) with Embree's required alignment.

    Returns an opaque ``ptr`` (as the LLVM backend uses throughout): address fields with
    ``builder.gep(p, field_indices(...), source_etype=llvm_rayhit_type(width))``. Emit it in
    the entry block, so that a loop reuses one stack slot."""
    ty = llvm_rayhit_type(width) if with_hit else llvm_ray_type(width)
    slot = builder.alloca(ty, name=name)
    slot.align = PacketLayout(width, with_hit).align
    # llvmlite types an alloca as a typed pointer, and a bitcast to `ptr` folds away (the two
    # compare equal); retype the result so that GEPs with source_etype yield opaque pointers
    slot.type = L.PointerType()
    return slot


def declare_query(module: L.Module, query: str, width: int) -> L.Function:
    """Declare ``rtcIntersect<width>`` or ``rtcOccluded<width>`` in an llvmlite module.

    Width 1: ``void (ptr scene, ptr rayhit, ptr args)``; packets:
    ``void (ptr valid, ptr scene, ptr rayhit, ptr args)`` where ``valid`` points to
    ``width`` i32 (-1 = active, 0 = inactive) aligned like the packet. ``args`` may be null."""
    if query not in QUERIES:
        raise ValueError(f"query: expected 'Intersect' or 'Occluded', got {query!r}")
    name = f"rtc{query}{check_width(width)}"
    if name in module.globals:
        return module.globals[name]
    ptr = L.PointerType()
    fnty = L.FunctionType(L.VoidType(), [ptr] * (3 if width == 1 else 4))
    return L.Function(module, fnty, name)


__all__ = ["alloca_packet", "declare_query", "field_indices", "llvm_hit_type", "llvm_ray_type",
           "llvm_rayhit_type"]
