"""The frontend's view of types: names, mangling, implicit conversions and literal rules.

Semantic types are the IR types of :mod:`rdsl.compiler.ir` (``F32``, ``VecType(3)``,
``StructType``...) plus :data:`TEXTURE` for texture params.  Void is ``None``.

The conversion rules live here so that the checker and the builtins agree on them: an
unsuffixed integer literal converts to any integer type or to ``Float`` (and broadcasts to a
float aggregate), and a ``Float`` broadcasts to a float vector or ``Spectrum``.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..compiler.diagnostics import CompileError, Diagnostic
from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    U64,
    UNPOLARIZED,
    BufferType,
    Loc,
    MatType,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    UnpolarizedType,
    VecType,
)
from . import ast as A


@dataclass(frozen=True)
class TextureType(Type):
    """The type of a ``Texture`` plugin param (an IR ``spectrum`` once lowered)."""

    def with_lanes(self, lanes: int) -> TextureType:
        return self

    def __str__(self) -> str:
        return "texture"


TEXTURE = TextureType()

BUILTIN_TYPES: dict[str, Type] = {
    "Float": F32, "Int": I32, "UInt": U32, "UInt64": U64, "Bool": BOOL,
    "Vec2": VecType(2), "Vec3": VecType(3), "Vec4": VecType(4), "Mat3": MatType(3),
    "Mat4": MatType(4), "Spectrum": SPECTRUM, "Unpolarized": UNPOLARIZED, "Texture": TEXTURE,
}
_SCALAR_NAMES = {"f32": "Float", "i32": "Int", "u32": "UInt", "u64": "UInt64", "bool": "Bool"}


def type_name(t: Type | None) -> str:
    """The source spelling of a type, for messages."""
    if t is None:
        return "()"
    if isinstance(t, ScalarType):
        return _SCALAR_NAMES[t.name]
    if isinstance(t, VecType):
        return f"Vec{t.n}"
    if isinstance(t, MatType):
        return f"Mat{t.n}"
    if isinstance(t, UnpolarizedType):
        return "Unpolarized"
    if isinstance(t, SpectrumType):
        return "Spectrum"
    if isinstance(t, TextureType):
        return "Texture"
    if isinstance(t, StructType):
        return t.name
    if isinstance(t, TupleType):
        return "(" + ", ".join(type_name(e) for e in t.elems) + ")"
    if isinstance(t, BufferType):
        return f"[{type_name(t.elem)}]"
    return str(t)


def quoted(t: Type | None) -> str:
    """A type name in backquotes, for messages."""
    return f"`{type_name(t)}`"


def err(message: str, loc: Loc | None) -> CompileError:
    """A one-diagnostic error at ``loc``, for the caller to raise."""
    return CompileError([Diagnostic(loc, message)])


def is_float_agg(t: Type | None) -> bool:
    """A float vector, ``Spectrum`` or matrix."""
    return (isinstance(t, VecType) and t.elem == F32) or isinstance(t, (SpectrumType, MatType))


def is_int_scalar(t: Type | None) -> bool:
    """``Int``, ``UInt`` or ``UInt64``."""
    return isinstance(t, ScalarType) and t.is_int


def is_numeric(t: Type | None) -> bool:
    """A non-``Bool`` scalar or a float aggregate: what arithmetic accepts."""
    return (isinstance(t, ScalarType) and t != BOOL) or is_float_agg(t)


def is_int_literal(e: A.Expr) -> bool:
    """An unsuffixed integer literal, possibly negated: convertible to Float/UInt/UInt64."""
    if isinstance(e, A.IntLit):
        return e.suffix == ""
    return isinstance(e, A.Unary) and e.op == "-" and is_int_literal(e.operand)


def _retype_literal(e: A.Expr, t: Type) -> None:
    e.ty = t
    if isinstance(e, A.Unary):
        _retype_literal(e.operand, t)


def mangle(t: Type) -> str:
    """A C-identifier-safe spelling of a type for overloaded function names."""
    if isinstance(t, ScalarType):
        return t.name
    if isinstance(t, VecType):
        return f"vec{t.n}"
    if isinstance(t, MatType):
        return f"mat{t.n}"
    if isinstance(t, UnpolarizedType):
        return "unpolarized"
    if isinstance(t, SpectrumType):
        return "spectrum"
    if isinstance(t, StructType):
        return t.name
    if isinstance(t, TupleType):
        return "tup" + "".join("_" + mangle(e) for e in t.elems) + "_end"
    if isinstance(t, BufferType):
        return "buf" + t.elem.name
    return "t"


# --------------------------------------------------------------------------------------
# Implicit conversions


def conv_cost(e: A.Expr, src: Type | None, dst: Type) -> int | None:
    """0: same type; 1: literal conversion; 2: broadcast; None: not convertible."""
    if src == dst:
        return 0
    if is_int_literal(e) and (dst in (F32, U32, U64) or dst == I32):
        return 1
    if is_int_literal(e) and (is_float_agg(dst) and not isinstance(dst, MatType)):
        return 2
    if src == F32 and (isinstance(dst, SpectrumType)
                       or (isinstance(dst, VecType) and dst.elem == F32)):
        return 2
    return None


def coerce(e: A.Expr, src: Type | None, dst: Type, what: str) -> A.Expr:
    """Convert ``e`` (of type ``src``) to ``dst`` or raise "what: expected .., found ..".
    """
    if src is None:
        raise err(f"{what}: expected {quoted(dst)}, found no value", e.loc)
    cost = conv_cost(e, src, dst)
    if cost is None:
        raise err(f"{what}: expected {quoted(dst)}, found {quoted(src)}", e.loc)
    return apply_conv(e, src, dst)


def apply_conv(e: A.Expr, src: Type | None, dst: Type) -> A.Expr:
    """``e`` converted to ``dst`` (the caller has checked that it converts)."""
    if src == dst:
        return e
    if is_int_literal(e):
        if is_float_agg(dst):
            _retype_literal(e, F32)
            c = A.Convert(e.loc, e, dst)
            c.ty = dst
            return c
        _retype_literal(e, dst)
        return e
    c = A.Convert(e.loc, e, dst)
    c.ty = dst
    return c


def unify(a: A.Expr, ta: Type, b: A.Expr, tb: Type) -> tuple[A.Expr, A.Expr, Type] | None:
    """Bring two operands to a common type (literals, Float broadcast); None if none."""
    la, lb = is_int_literal(a), is_int_literal(b)
    if la and not lb and tb is not None:
        tgt = F32 if is_float_agg(tb) else tb
        if conv_cost(a, ta, tgt) is not None:
            a, ta = apply_conv(a, ta, tgt), tgt
    elif lb and not la and ta is not None:
        tgt = F32 if is_float_agg(ta) else ta
        if conv_cost(b, tb, tgt) is not None:
            b, tb = apply_conv(b, tb, tgt), tgt
    if ta == tb:
        return a, b, ta
    if ta == F32 and is_float_agg(tb) and not isinstance(tb, MatType):
        return apply_conv(a, ta, tb), b, tb
    if tb == F32 and is_float_agg(ta) and not isinstance(ta, MatType):
        return a, apply_conv(b, tb, ta), ta
    if ta == F32 and isinstance(tb, MatType):
        return apply_conv(a, ta, tb), b, tb
    if tb == F32 and isinstance(ta, MatType):
        return a, apply_conv(b, tb, ta), ta
    return None


# --------------------------------------------------------------------------------------
# Literals and constants


_RANGES = {I32: (-2**31, 2**31 - 1), U32: (0, 2**32 - 1), U64: (0, 2**64 - 1)}


def check_literals(node: Any) -> None:
    """Integer literals must fit their final type (known only after conversions)."""
    stack = [node]
    while stack:
        n = stack.pop()
        if isinstance(n, list):
            stack.extend(n)
            continue
        if not hasattr(n, "__dataclass_fields__"):
            continue
        if isinstance(n, A.Unary) and n.op == "-" and isinstance(n.operand, A.IntLit):
            _lit_range(n.operand, -n.operand.value, n.loc)
            continue
        if isinstance(n, A.IntLit):
            _lit_range(n, n.value, n.loc)
            continue
        for f in _node_fields(n.__class__):
            v = getattr(n, f)
            if isinstance(v, (list, A.Expr, A.Stmt, A.FieldInit, A.PatName, A.PatTuple)):
                stack.append(v)


# annotations of fields that never hold a node (a fifth of a compile's checking went to
# looking at them, for every node of every function)
_LEAF_FIELDS = frozenset({"Loc", "Loc | None", "str", "int", "float", "bool", "list[str]"})


@functools.lru_cache(maxsize=None)
def _node_fields(cls: type) -> tuple[str, ...]:
    """The fields of AST class ``cls`` that may hold nodes."""
    return tuple(f.name for f in dataclasses.fields(cls) if str(f.type) not in _LEAF_FIELDS)


def _lit_range(lit: A.IntLit, value: int, loc: Loc) -> None:
    rng = _RANGES.get(lit.ty)
    if rng is not None and not rng[0] <= value <= rng[1]:
        raise err(f"integer literal `{lit.text}` is out of range for {quoted(lit.ty)}", loc)


def plugin_default(pp: A.PluginParam, t: Type) -> Any:
    """The python value of a plugin param default (a constant expression)."""
    e = pp.default
    bad = err(f"the default of plugin param `{pp.name}` must be a constant of type "
              f"{quoted(t)}", e.loc if e is not None else pp.loc)

    def num(x: A.Expr) -> float | int | None:
        if isinstance(x, (A.IntLit, A.FloatLit)):
            return x.value
        if isinstance(x, A.Unary) and x.op == "-":
            v = num(x.operand)
            return None if v is None else -v
        return None

    def f32(v: float) -> float:
        return float(np.float32(v))

    v = num(e)
    if t == F32 or isinstance(t, (SpectrumType, TextureType)):
        if v is not None and not (isinstance(e, A.IntLit) and e.suffix):
            return f32(v)
        if isinstance(e, A.Call) and isinstance(e.func, A.Name) and \
                e.func.id == "Spectrum" and isinstance(t, (SpectrumType, TextureType)):
            vals = [num(a) for a in e.args]
            if len(vals) in (1, 3) and None not in vals:
                return f32(vals[0]) if len(vals) == 1 else tuple(f32(x) for x in vals)
        raise bad
    if isinstance(t, VecType):
        if v is not None:
            return tuple([f32(v)] * t.n)
        if isinstance(e, A.Call) and isinstance(e.func, A.Name) and e.func.id == f"Vec{t.n}":
            vals = [num(a) for a in e.args]
            if len(vals) in (1, t.n) and None not in vals:
                return tuple(f32(x) for x in (vals * t.n if len(vals) == 1 else vals))
        raise bad
    if t == BOOL:
        if isinstance(e, A.BoolLit):
            return e.value
        raise bad
    if is_int_scalar(t):
        lit = e.operand if isinstance(e, A.Unary) else e
        if isinstance(v, int) and isinstance(lit, A.IntLit) and \
                lit.suffix in ("", {U32: "u", U64: "ul"}.get(t, "")):
            lo, hi = _RANGES[t]
            if lo <= v <= hi:
                return v
        raise bad
    raise bad
