"""The kernel ABI's view of IR types: their JSON description (kernel manifests) and their
scalar leaves in flattening order (what ``scalarize`` splits an aggregate into)."""

from __future__ import annotations

from typing import Any

from . import ir
from .ir import ScalarType, Type


def type_to_json(t: Type) -> dict[str, Any]:
    """A JSON description of a (source-level) type, used by kernel manifests.

    Leaves are flattened depth-first: struct fields in declaration order, tuple elements in
    order, vector components x, y, z, w, matrix entries row-major."""
    if isinstance(t, ScalarType):
        return {"kind": "scalar", "dtype": t.name}
    if isinstance(t, ir.VecType):
        return {"kind": "vec", "n": t.n, "dtype": t.elem.name}
    if isinstance(t, ir.MatType):
        return {"kind": "mat", "n": t.n, "dtype": "f32"}
    if isinstance(t, ir.StructType):
        return {"kind": "struct", "name": t.name,
                "fields": [[n, type_to_json(ft)] for n, ft in t.fields]}
    if isinstance(t, ir.TupleType):
        return {"kind": "tuple", "elems": [type_to_json(e) for e in t.elems]}
    if isinstance(t, ir.BufferType):
        return {"kind": "buffer", "dtype": t.elem.name}
    if isinstance(t, ir.UnpolarizedType):
        return {"kind": "unpolarized"}
    if isinstance(t, ir.SpectrumType):
        return {"kind": "spectrum"}
    raise TypeError(t)


def leaf_types(t: Type) -> list[ScalarType]:
    """The scalar leaves of a concrete type in flattening order (see :func:`type_to_json`)."""
    if isinstance(t, ScalarType):
        return [t]
    if isinstance(t, ir.BufferType):
        return []
    out: list[ScalarType] = []
    for c in ir.components(t):
        out.extend(leaf_types(c))
    return out
