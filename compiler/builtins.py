"""The builtin functions of the language, declared once, and the exact semantics of the math
intrinsics they lower to.

``BUILTINS`` maps each builtin's name to a :class:`Builtin`: its signature rule (checked by
``dsl/builtins.py``, one checking function per :class:`Sig`) and its lowering (an IR op the
call becomes one to one, or a rule that expands it).  ``F32_INTRINSICS`` gives, per unary
f32 math op, its numpy evaluation (the interpreter's and so the constant folder's) and the
LLVM intrinsic that computes the same bits.  A new builtin on an existing signature rule is
one entry here; a new math op adds its ``Op`` (``ir.py``) and its ``F32_INTRINSICS`` entry.

This module sits next to the IR so that the frontend, the interpreter and the backends can
all read it; it imports nothing above ``compiler.ir``.
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    U64,
    UNPOLARIZED,
    Builder,
    MatType,
    Op,
    Type,
    UnpolarizedType,
    Value,
    VecType,
)


class Sig(enum.Enum):
    """The signature rules of builtins: which arguments a call takes and what it returns."""

    FIXED = "fixed"  # the argument types ``params`` -> ``result``
    FLOAT_MAP = "float_map"  # a Float, float vector or Spectrum -> the same type
    NUMBER_MAP = "number_map"  # as FLOAT_MAP, or an integer scalar -> the same type
    MIN_MAX = "min_max"  # two values of one Float-like or integer type -> that type
    SELECT = "select"  # a Bool and two values of one type -> that type
    CONVERT = "convert"  # one scalar -> ``result``
    CONSTRUCT = "construct"  # Floats and vectors with ``result``'s components -> ``result``
    SPECTRUM = "spectrum"  # an Unpolarized, or 1, 3 or 4 Floats -> Spectrum
    ILLUMINANT = "illuminant"  # 3 or 4 Floats -> Spectrum
    MUELLER = "mueller"  # 16 Unpolarized entries, row-major -> Spectrum
    MUELLER_ENTRY = "mueller_entry"  # a Spectrum and two integer literals 0..3 -> Unpolarized
    REDUCE = "reduce"  # an Unpolarized or a Spectrum -> Float
    RAY = "ray"  # a ``Ray`` -> ``result`` (a type, or the name of a stdlib struct)


# A lowering rule: (builder at the call's location, the call's IR type or None, the lowered
# arguments, the arguments' literal values or None) -> the call's value, or None for none.
Lowering = Callable[[Builder, "Type | None", list[Value], list[Any]], "Value | None"]


@dataclass(frozen=True)
class Builtin:
    """One builtin function: ``sig`` (with ``params`` and ``result`` where the rule needs
    them) types its calls; ``lower`` is the op a call becomes, its arguments the operands and
    its type the result's, or a rule that expands the call.  ``effects``: a call must not be
    evaluated speculatively (the right side of ``&&`` and ``||``)."""

    name: str
    sig: Sig
    lower: Op | Lowering
    params: tuple[Type, ...] = ()
    result: Type | str | None = None
    effects: bool = False

    def emit(self, b: Builder, t: Type | None, args: list[Value],
             literals: list[Any]) -> Value | None:
        """Lower a call of this builtin into ``b``."""
        if isinstance(self.lower, Op):
            assert t is not None, self.name
            return b.op(self.lower, t, *args)
        return self.lower(b, t, args, literals)


# --------------------------------------------------------------------------------------
# Lowering rules of the builtins that are not one op


def _set_wavelengths(b: Builder, t: Type | None, args: list[Value],
                     literals: list[Any]) -> Value | None:
    b.emit(Op.SPEC_SET, args, [])
    return None


def _convert(b: Builder, t: Type | None, args: list[Value], literals: list[Any]) -> Value:
    assert t is not None
    return args[0] if args[0].type == t else b.op(Op.CAST, t, args[0])


def _construct(b: Builder, t: Type | None, args: list[Value], literals: list[Any]) -> Value:
    assert isinstance(t, (VecType, MatType))
    if len(args) == 1 and isinstance(t, VecType):
        return b.op(Op.BROADCAST, t, args[0])
    comps: list[Value] = []
    for a in args:
        if isinstance(a.type, VecType):
            comps += [b.op(Op.EXTRACT, F32, a, index=i) for i in range(a.type.n)]
        else:
            comps.append(a)
    return b.op(Op.MAKE, t, *comps)


def _spectrum(b: Builder, t: Type | None, args: list[Value], literals: list[Any]) -> Value:
    assert t is not None
    if len(args) == 1:
        # u times the identity (u itself when unpolarized), or a grey
        op = Op.SPEC_FROM if isinstance(args[0].type, UnpolarizedType) else Op.BROADCAST
        return b.op(op, t, args[0])
    return b.op(Op.SPEC_RGB if len(args) == 3 else Op.SPEC_MAKE, t, *args)


def _illuminant(b: Builder, t: Type | None, args: list[Value], literals: list[Any]) -> Value:
    assert t is not None
    return b.op(Op.SPEC_RGB, t, *args, illuminant=True)


def _mueller_entry(b: Builder, t: Type | None, args: list[Value],
                   literals: list[Any]) -> Value:
    assert t is not None
    row, col = (int(x) for x in literals[1:])
    return b.op(Op.SPEC_ENTRY, t, args[0], row=row, col=col)


# --------------------------------------------------------------------------------------
# The table


def _table(*entries: Builtin) -> dict[str, Builtin]:
    return {e.name: e for e in entries}


BUILTINS: dict[str, Builtin] = _table(
    # math: one op each, elementwise on vectors and spectra
    Builtin("sqrt", Sig.FLOAT_MAP, Op.SQRT),
    # automatic differentiation (compiler/passes/ad_forward.py)
    Builtin("derivative", Sig.FLOAT_MAP, Op.DERIV),
    Builtin("detach", Sig.FLOAT_MAP, Op.DETACH),
    Builtin("floor", Sig.FLOAT_MAP, Op.FLOOR),
    Builtin("ceil", Sig.FLOAT_MAP, Op.CEIL),
    Builtin("abs", Sig.NUMBER_MAP, Op.ABS),
    Builtin("min", Sig.MIN_MAX, Op.MIN),
    Builtin("max", Sig.MIN_MAX, Op.MAX),
    Builtin("select", Sig.SELECT, Op.SELECT),
    Builtin("bits", Sig.FIXED, Op.BITCAST, (F32,), U32),
    Builtin("from_bits", Sig.FIXED, Op.BITCAST, (U32,), F32),
    # conversions and constructors: the builtin type of that name
    Builtin("Float", Sig.CONVERT, _convert, result=F32),
    Builtin("Int", Sig.CONVERT, _convert, result=I32),
    Builtin("UInt", Sig.CONVERT, _convert, result=U32),
    Builtin("UInt64", Sig.CONVERT, _convert, result=U64),
    Builtin("Bool", Sig.CONVERT, _convert, result=BOOL),
    Builtin("Vec2", Sig.CONSTRUCT, _construct, result=VecType(2)),
    Builtin("Vec3", Sig.CONSTRUCT, _construct, result=VecType(3)),
    Builtin("Vec4", Sig.CONSTRUCT, _construct, result=VecType(4)),
    Builtin("Mat3", Sig.CONSTRUCT, _construct, result=MatType(3)),
    Builtin("Mat4", Sig.CONSTRUCT, _construct, result=MatType(4)),
    # colour
    Builtin("Spectrum", Sig.SPECTRUM, _spectrum),
    Builtin("illuminant", Sig.ILLUMINANT, _illuminant),
    Builtin("mean", Sig.REDUCE, Op.SPEC_AVG),
    Builtin("max_value", Sig.REDUCE, Op.SPEC_MAX),
    Builtin("set_wavelengths", Sig.FIXED, _set_wavelengths, (SPECTRUM,), None),
    Builtin("wavelengths", Sig.FIXED, Op.SPEC_LAMBDA, (), SPECTRUM),
    Builtin("to_srgb", Sig.FIXED, Op.SPEC_SRGB, (SPECTRUM,), VecType(3)),
    # polarization
    Builtin("Unpolarized", Sig.FIXED, Op.BROADCAST, (F32,), UNPOLARIZED),
    Builtin("unpolarized", Sig.FIXED, Op.SPEC_UNPOL, (SPECTRUM,), UNPOLARIZED),
    Builtin("depolarizer", Sig.FIXED, Op.SPEC_DEPOL, (UNPOLARIZED,), SPECTRUM),
    Builtin("mueller", Sig.MUELLER, Op.SPEC_MUELLER),
    Builtin("mueller_entry", Sig.MUELLER_ENTRY, _mueller_entry),
    # SIMD: whether `b` holds in any active lane (a uniform value: the lanes of a vectorized
    # kernel then take the same branch, e.g. a packet of rays one BVH node; `b` itself
    # where a lane runs alone)
    Builtin("any_lane", Sig.FIXED, Op.ANY, (BOOL,), BOOL),
    # ray queries
    Builtin("trace", Sig.RAY, Op.INTERSECT, result="Hit", effects=True),
    Builtin("occluded", Sig.RAY, Op.OCCLUDED, result=BOOL, effects=True),
)


# --------------------------------------------------------------------------------------
# Math intrinsics


@dataclass(frozen=True)
class Intrinsic:
    """The exact f32 semantics of a unary math op: ``f32`` evaluates it on a
    ``numpy.float32`` (the interpreter and the constant folder), ``llvm`` names the LLVM
    intrinsic (``llvm.<name>.<type>``) that gives the same bits."""

    f32: Callable[[np.float32], Any]
    llvm: str


F32_INTRINSICS: dict[Op, Intrinsic] = {
    Op.SQRT: Intrinsic(np.sqrt, "sqrt"),
    Op.FLOOR: Intrinsic(np.floor, "floor"),
    Op.CEIL: Intrinsic(np.ceil, "ceil"),
}
