"""The builtin functions, constructors and operators, and how their uses are checked.

A user function of the same name overloads a builtin: the checker tries the builtin first
and falls back to the user's overloads when the builtin rejects the arguments.
"""

from __future__ import annotations

from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    U32,
    UNPOLARIZED,
    BufferType,
    MatType,
    ScalarType,
    StructType,
    Type,
    VecType,
)
from . import ast as A
from .types import (
    BUILTIN_TYPES,
    apply_conv,
    conv_cost,
    err,
    is_float_agg,
    is_int_literal,
    is_int_scalar,
    is_numeric,
    quoted,
    type_name,
    unify,
)

BUILTIN_FNS = {
    "sqrt", "floor", "ceil", "abs", "min", "max", "select", "bits", "from_bits", "Float", "Int",
    "UInt", "UInt64", "Bool", "Vec2", "Vec3", "Vec4", "Mat3", "Mat4", "Spectrum", "mean",
    "max_value", "trace", "occluded", "illuminant", "set_wavelengths", "wavelengths", "to_srgb",
    "Unpolarized", "unpolarized", "depolarizer", "mueller", "mueller_entry",
}


# builtins of one fixed signature: (argument types, result type; None for no value)
_FIXED: dict[str, tuple[tuple[Type, ...], Type | None]] = {
    "bits": ((F32,), U32),
    "from_bits": ((U32,), F32),
    "Unpolarized": ((F32,), UNPOLARIZED),
    "unpolarized": ((SPECTRUM,), UNPOLARIZED),
    "depolarizer": ((UNPOLARIZED,), SPECTRUM),
    "set_wavelengths": ((SPECTRUM,), None),
    "wavelengths": ((), SPECTRUM),
    "to_srgb": ((SPECTRUM,), VecType(3)),
}


def check_builtin(e: A.Call, name: str, args: list[A.Expr], types: list[Type | None],
                  structs: dict[str, StructType]) -> Type | None:
    """Check a call of builtin ``name``; annotate ``e`` and return its result type.

    ``args`` and ``types`` are the call's arguments (the receiver first for a method call)
    and their types; arguments that need an implicit conversion are wrapped in place.
    """
    loc = e.func.loc if isinstance(e.func, A.Name) else (e.func.name_loc or e.loc)

    def nargs(*counts: int) -> None:
        if len(args) not in counts:
            want = " or ".join(str(c) for c in counts)
            raise err(f"`{name}` takes {want} argument{'s' if counts != (1,) else ''}, "
                      f"found {len(args)}", loc)

    def arg(i: int, want: Type) -> None:
        if conv_cost(args[i], types[i], want) is None:
            raise err(f"argument {i + 1} of `{name}`: expected {quoted(want)}, found "
                      f"{quoted(types[i])}", args[i].loc)
        args[i] = apply_conv(args[i], types[i], want)
        types[i] = want

    def finish(t: Type | None, kind: str = "op") -> Type | None:
        e.args = args
        e.target = ("builtin", name)
        return t

    float_like = lambda t: t == F32 or (is_float_agg(t) and not isinstance(t, MatType))
    if name in _FIXED:
        params, result = _FIXED[name]
        nargs(len(params))
        for i, want in enumerate(params):
            arg(i, want)
        return finish(result)
    if name in ("sqrt", "floor", "ceil", "abs"):
        nargs(1)
        if is_int_literal(args[0]):
            arg(0, F32)
        t = types[0]
        if float_like(t) or (name == "abs" and is_int_scalar(t)):
            return finish(t)
        raise err(f"`{name}` expects `Float`, a vector or `Spectrum`, found {quoted(t)}",
                  args[0].loc)
    if name in ("min", "max"):
        nargs(2)
        u = unify(args[0], types[0], args[1], types[1])
        if u is not None and is_int_literal(u[0]) and is_int_literal(u[1]):
            u = (u[0], u[1], I32)
        if u is None or not (float_like(u[2]) or is_int_scalar(u[2])):
            raise err(f"no matching overload for `{name}({type_name(types[0])}, "
                      f"{type_name(types[1])})`", loc)
        args[0], args[1], t = u
        return finish(t)
    if name == "select":
        nargs(3)
        if types[0] != BOOL:
            raise err(f"argument 1 of `select`: expected `Bool`, found {quoted(types[0])}",
                      args[0].loc)
        u = unify(args[1], types[1], args[2], types[2])
        if u is None:
            raise err(f"`select` needs two values of the same type, found {quoted(types[1])} "
                      f"and {quoted(types[2])}", loc)
        args[1], args[2], t = u
        return finish(t)
    if name in ("Float", "Int", "UInt", "UInt64", "Bool"):
        nargs(1)
        t = types[0]
        if not isinstance(t, ScalarType):
            raise err(f"cannot convert {quoted(t)} to `{name}`", args[0].loc)
        return finish(BUILTIN_TYPES[name])
    if name in ("Vec2", "Vec3", "Vec4", "Mat3", "Mat4"):
        want = BUILTIN_TYPES[name]
        n = want.n if isinstance(want, VecType) else want.n * want.n  # type: ignore
        if len(args) == 1 and isinstance(want, VecType):
            arg(0, F32)
            return finish(want)
        total = 0
        for i, t in enumerate(types):
            if is_int_literal(args[i]):
                arg(i, F32)
                t = F32
            if t == F32:
                total += 1
            elif isinstance(t, VecType):
                total += t.n
            else:
                raise err(f"argument {i + 1} of `{name}`: expected `Float` or a vector, "
                          f"found {quoted(t)}", args[i].loc)
        if total != n:
            raise err(f"`{name}` needs {n} components, found {total}", loc)
        return finish(want)
    if name == "Spectrum" and len(args) == 1 and types[0] == UNPOLARIZED:
        return finish(SPECTRUM)  # u times the identity (u itself when unpolarized)
    if name in ("Spectrum", "illuminant"):
        nargs(*((1, 3, 4) if name == "Spectrum" else (3, 4)))
        for i in range(len(args)):
            arg(i, F32)
        return finish(SPECTRUM)
    if name == "mueller":
        nargs(16)
        for i in range(16):
            arg(i, UNPOLARIZED)
        return finish(SPECTRUM)
    if name == "mueller_entry":
        nargs(3)
        arg(0, SPECTRUM)
        for i in (1, 2):
            a = args[i]
            if not (isinstance(a, A.IntLit) and a.suffix == "" and 0 <= a.value <= 3):
                raise err(f"argument {i + 1} of `mueller_entry`: expected an integer literal "
                          "0..3", a.loc)
        return finish(UNPOLARIZED)
    if name in ("mean", "max_value"):
        nargs(1)
        if types[0] != UNPOLARIZED:
            arg(0, SPECTRUM)
        return finish(F32)
    if name == "trace":
        nargs(1)
        arg(0, structs.get("Ray") or StructType("Ray"))
        return finish(structs.get("Hit"))
    if name == "occluded":
        nargs(1)
        arg(0, structs.get("Ray") or StructType("Ray"))
        return finish(BOOL)
    raise err(f"unknown function `{name}`", loc)  # pragma: no cover


# --------------------------------------------------------------------------------------
# Operators


_ARITH_VERB = {"+": "add", "-": "subtract", "*": "multiply", "/": "divide", "%": "take the "
               "remainder of"}


def check_unary(e: A.Unary, t: Type | None) -> Type:
    """The type of unary ``e`` whose operand has type ``t``."""
    ok = {"-": is_numeric(t), "!": t == BOOL, "~": is_int_scalar(t)}
    if ok.get(e.op):
        return t
    raise err(f"cannot apply unary `{e.op}` to {quoted(t)}", e.loc)


def check_binary(e: A.Binary, ta: Type | None, tb: Type | None) -> Type:
    """The type of binary ``e`` with operand types ``ta`` and ``tb``; literal operands are
    converted and a ``Float`` operand is broadcast to the other's type, in place."""
    op = e.op
    if op in ("&&", "||"):
        for x, t in ((e.left, ta), (e.right, tb)):
            if t != BOOL:
                raise err(f"operands of `{op}` must be `Bool`, found {quoted(t)}", x.loc)
        return BOOL
    u = unify(e.left, ta, e.right, tb)
    if u is not None:
        e.left, e.right, t = u
    else:
        t = None
    if op in _ARITH_VERB:
        if t is not None and is_numeric(t) and not (
                isinstance(t, MatType) and op in ("*", "/", "%")
                and ta == tb):
            return t
        verb = _ARITH_VERB[op]
        raise err(f"cannot {verb} {quoted(ta)} and {quoted(tb)}", e.loc)
    if op in ("&", "|", "^"):
        if t is not None and (is_int_scalar(t) or t == BOOL):
            return t
        raise err(f"cannot apply `{op}` to {quoted(ta)} and {quoted(tb)}", e.loc)
    if op in ("<<", ">>"):
        if t is not None and is_int_scalar(t):
            return t
        raise err(f"cannot shift {quoted(ta)} by {quoted(tb)}", e.loc)
    if op in ("==", "!=", "<", "<=", ">", ">="):
        if ta is not None and tb is not None and (
                ta.is_aggregate or tb.is_aggregate or isinstance(ta, BufferType)):
            raise err(f"cannot compare {quoted(ta)} and {quoted(tb)}: comparisons are on "
                      "scalars only", e.loc)
        if t is not None and isinstance(t, ScalarType) and (t != BOOL or op in ("==", "!=")):
            return BOOL
        raise err(f"cannot compare {quoted(ta)} and {quoted(tb)}", e.loc)
    raise err(f"unknown operator `{op}`", e.loc)  # pragma: no cover
