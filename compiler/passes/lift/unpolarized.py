"""The lowering of spectrum ops on unpolarized values, one rule per op in ``_RULES``.

A mono spectrum is an ``f32``, an RGB one a ``vec3``; spectral variants hand their colour
ops to :class:`~.spectral.Spectral`.  Unpolarized variants read a spectrum as depolarized
light: only its intensity entry [0][0] exists.  The Mueller lowering also comes here for
the unpolarized entries of its matrices.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from ...diagnostics import CompileError, Diagnostic
from ...ir import F32, Builder, Instr, Op, ScalarType, Value

if TYPE_CHECKING:
    from .driver import Lift

# CIE Y weights of linear sRGB primaries: what a mono variant sees of an RGB value.
_LUMINANCE = (0.212671, 0.715160, 0.072169)

Rule = Callable[["Lift", Instr, Builder, list[Value]], "Value | None"]


def fail(ins: Instr, msg: str) -> CompileError:
    """A diagnostic at ``ins``."""
    return CompileError([Diagnostic(ins.loc, msg)])


def rewrite_unpolarized(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    """Return the replacement of ``ins``'s result, or None to keep ``ins``.  Unpolarized
    values only: ``ins.type`` is the concrete spectrum (or what a spectrum op gives)."""
    rule = _RULES.get(ins.op)
    return None if rule is None else rule(lift, ins, b, ops)


def _reduce(lift: Lift, b: Builder, v: Value, op: Op, divide: bool = False) -> Value:
    n = lift.model.n
    if n == 1:
        return v
    parts = [b.op(Op.EXTRACT, F32, v, index=i) for i in range(n)]
    acc = parts[0]
    for p in parts[1:]:
        acc = b.op(op, F32, acc, p)
    if divide:
        acc = b.op(Op.DIV, F32, acc, b.const(float(n), F32))
    return acc


def _broadcast(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    if lift.model.n == 1 and isinstance(ops[0].type, ScalarType) and ins.type == ops[0].type:
        return ops[0]
    return None


def _avg(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    return _reduce(lift, b, ops[0], Op.ADD, divide=True)


def _max(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    return _reduce(lift, b, ops[0], Op.MAX)


def _make(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    n = lift.model.n
    if len(ops) != n:
        raise fail(ins, f"a Spectrum of {len(ops)} components does not exist in the "
                   f"`{lift.model.name}` variant ({n} component{'s' if n > 1 else ''}); "
                   "use it inside `if const`")
    return b.op(Op.MAKE, ins.type, *ops) if n > 1 else ops[0]


def _wavelengths(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    if lift.spectral is None:
        raise fail(ins, f"`wavelengths()` has no meaning in the `{lift.model.name}` "
                   "variant; use it inside `if const spectral`")
    return lift.spectral.lam(ins)


def _to_srgb(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    n = lift.model.n
    if n == 3:
        return ops[0]
    if n == 1:
        return b.op(Op.MAKE, ins.type, ops[0], ops[0], ops[0])
    return lift.spectral.to_srgb(b, ins, ops[0])  # type: ignore[union-attr]


def _from_rgb(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    n = lift.model.n
    illum = bool(ins.attrs.get("illuminant"))
    if n == 4:
        return lift.spectral.from_rgb(b, ins, ops, illum)  # type: ignore[union-attr]
    rgb = ops[:3]
    if n == 3:
        out = b.op(Op.MAKE, ins.type, *rgb)
        return out if len(ops) == 3 else b.op(Op.MUL, ins.type, out,
                                              b.op(Op.BROADCAST, ins.type, ops[3]))
    acc = None
    for w, v in zip(_LUMINANCE, rgb):
        term = b.op(Op.MUL, F32, b.const(w, F32), v)
        acc = term if acc is None else b.op(Op.ADD, F32, acc, term)
    return acc if len(ops) == 3 else b.op(Op.MUL, F32, acc, ops[3])


def _table(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    if lift.spectral is None:
        raise fail(ins, "a tabulated spectrum read from a buffer exists in spectral variants "
                   f"only (this is `{lift.model.name}`)")
    return lift.spectral.stored_table(b, ins, ops[0], ops[1])


def _select(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    return lift.spectral.select(b, ins, ops) if lift.spectral is not None else None


def _itself(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    """A spectrum is its own unpolarized part, and is read as depolarized light."""
    return ops[0]


def _entry(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    if (ins.attrs["row"], ins.attrs["col"]) == (0, 0):
        return ops[0]
    zero = b.const(0.0, F32)
    return zero if lift.model.n == 1 else b.op(Op.BROADCAST, ins.type, zero)


def _mueller(lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
    raise fail(ins, "`mueller(...)` builds a Mueller matrix, which exists in polarized "
               f"variants only (this is `{lift.model.name}`); use it inside "
               "`if const polarized`")


_RULES: dict[Op, Rule] = {
    Op.BROADCAST: _broadcast,
    Op.SPEC_AVG: _avg,
    Op.SPEC_MAX: _max,
    Op.SPEC_MAKE: _make,
    Op.SPEC_LAMBDA: _wavelengths,
    Op.SPEC_SRGB: _to_srgb,
    Op.SPEC_RGB: _from_rgb,
    Op.SPEC_TABLE: _table,
    Op.SELECT: _select,
    Op.SPEC_UNPOL: _itself,
    Op.SPEC_FROM: _itself,
    Op.SPEC_DEPOL: _itself,
    Op.SPEC_ENTRY: _entry,
    Op.SPEC_MUELLER: _mueller,
}
