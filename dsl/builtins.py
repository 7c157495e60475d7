"""How calls of builtin functions, and the operators, are checked.

The builtins themselves are declared in ``compiler/builtins.py`` (``BUILTINS``): each names
a signature rule (:class:`~rdsl.compiler.builtins.Sig`), and ``_RULES`` here checks each rule
once.  A user function of the same name overloads a builtin: the checker tries the builtin
first and falls back to the user's overloads when the builtin rejects the arguments.
"""

from __future__ import annotations

from collections.abc import Callable

from ..compiler.builtins import BUILTINS, Builtin, Sig
from ..compiler.ir import (
    BOOL,
    F32,
    I32,
    SPECTRUM,
    UNPOLARIZED,
    BufferType,
    Loc,
    MatType,
    ScalarType,
    StructType,
    Type,
    VecType,
)
from . import ast as A
from .types import (
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

BUILTIN_FNS = frozenset(BUILTINS)


class _Call:
    """A call of a builtin being checked: its arguments (the receiver first for a method
    call) and their types, converted in place as the rule requires."""

    def __init__(self, e: A.Call, name: str, args: list[A.Expr], types: list[Type | None],
                 structs: dict[str, StructType]) -> None:
        self.e = e
        self.name = name
        self.args = args
        self.types = types
        self.structs = structs
        self.loc: Loc = e.func.loc if isinstance(e.func, A.Name) else (e.func.name_loc or e.loc)

    def nargs(self, *counts: int) -> None:
        if len(self.args) not in counts:
            want = " or ".join(str(c) for c in counts)
            raise err(f"`{self.name}` takes {want} argument{'s' if counts != (1,) else ''}, "
                      f"found {len(self.args)}", self.loc)

    def arg(self, i: int, want: Type) -> None:
        """Argument ``i`` converts to ``want``; convert it."""
        args, types = self.args, self.types
        if conv_cost(args[i], types[i], want) is None:
            raise err(f"argument {i + 1} of `{self.name}`: expected {quoted(want)}, found "
                      f"{quoted(types[i])}", args[i].loc)
        args[i] = apply_conv(args[i], types[i], want)
        types[i] = want

    def finish(self, t: Type | None) -> Type | None:
        self.e.args = self.args
        self.e.target = ("builtin", self.name)
        return t


def check_builtin(e: A.Call, name: str, args: list[A.Expr], types: list[Type | None],
                  structs: dict[str, StructType]) -> Type | None:
    """Check a call of builtin ``name``; annotate ``e`` and return its result type.

    ``args`` and ``types`` are the call's arguments (the receiver first for a method call)
    and their types; arguments that need an implicit conversion are wrapped in place.
    """
    b = BUILTINS[name]
    return _RULES[b.sig](_Call(e, name, args, types, structs), b)


def _float_like(t: Type | None) -> bool:
    return t == F32 or (is_float_agg(t) and not isinstance(t, MatType))


# --------------------------------------------------------------------------------------
# One checking function per signature rule


def _fixed(c: _Call, b: Builtin) -> Type | None:
    c.nargs(len(b.params))
    for i, want in enumerate(b.params):
        c.arg(i, want)
    return c.finish(b.result)  # type: ignore[arg-type]


def _float_map(c: _Call, b: Builtin) -> Type | None:
    c.nargs(1)
    if is_int_literal(c.args[0]):
        c.arg(0, F32)
    t = c.types[0]
    if _float_like(t) or (b.sig is Sig.NUMBER_MAP and is_int_scalar(t)):
        return c.finish(t)
    raise err(f"`{c.name}` expects `Float`, a vector or `Spectrum`, found {quoted(t)}",
              c.args[0].loc)


def _min_max(c: _Call, b: Builtin) -> Type | None:
    c.nargs(2)
    args, types = c.args, c.types
    u = unify(args[0], types[0], args[1], types[1])
    if u is not None and is_int_literal(u[0]) and is_int_literal(u[1]):
        u = (u[0], u[1], I32)
    if u is None or not (_float_like(u[2]) or is_int_scalar(u[2])):
        raise err(f"no matching overload for `{c.name}({type_name(types[0])}, "
                  f"{type_name(types[1])})`", c.loc)
    args[0], args[1], t = u
    return c.finish(t)


def _select(c: _Call, b: Builtin) -> Type | None:
    c.nargs(3)
    args, types = c.args, c.types
    if types[0] != BOOL:
        raise err(f"argument 1 of `select`: expected `Bool`, found {quoted(types[0])}",
                  args[0].loc)
    u = unify(args[1], types[1], args[2], types[2])
    if u is None:
        raise err(f"`select` needs two values of the same type, found {quoted(types[1])} "
                  f"and {quoted(types[2])}", c.loc)
    args[1], args[2], t = u
    return c.finish(t)


def _convert(c: _Call, b: Builtin) -> Type | None:
    c.nargs(1)
    t = c.types[0]
    if not isinstance(t, ScalarType):
        raise err(f"cannot convert {quoted(t)} to `{c.name}`", c.args[0].loc)
    return c.finish(b.result)  # type: ignore[arg-type]


def _construct(c: _Call, b: Builtin) -> Type | None:
    want = b.result
    assert isinstance(want, (VecType, MatType))
    n = want.n if isinstance(want, VecType) else want.n * want.n
    if len(c.args) == 1 and isinstance(want, VecType):
        c.arg(0, F32)
        return c.finish(want)
    total = 0
    for i, t in enumerate(c.types):
        if is_int_literal(c.args[i]):
            c.arg(i, F32)
            t = F32
        if t == F32:
            total += 1
        elif isinstance(t, VecType):
            total += t.n
        else:
            raise err(f"argument {i + 1} of `{c.name}`: expected `Float` or a vector, "
                      f"found {quoted(t)}", c.args[i].loc)
    if total != n:
        raise err(f"`{c.name}` needs {n} components, found {total}", c.loc)
    return c.finish(want)


def _spectrum(c: _Call, b: Builtin) -> Type | None:
    if len(c.args) == 1 and c.types[0] == UNPOLARIZED:
        return c.finish(SPECTRUM)  # u times the identity (u itself when unpolarized)
    return _floats(c, (1, 3, 4))


def _illuminant(c: _Call, b: Builtin) -> Type | None:
    return _floats(c, (3, 4))


def _floats(c: _Call, counts: tuple[int, ...]) -> Type | None:
    c.nargs(*counts)
    for i in range(len(c.args)):
        c.arg(i, F32)
    return c.finish(SPECTRUM)


def _mueller(c: _Call, b: Builtin) -> Type | None:
    c.nargs(16)
    for i in range(16):
        c.arg(i, UNPOLARIZED)
    return c.finish(SPECTRUM)


def _mueller_entry(c: _Call, b: Builtin) -> Type | None:
    c.nargs(3)
    c.arg(0, SPECTRUM)
    for i in (1, 2):
        a = c.args[i]
        if not (isinstance(a, A.IntLit) and a.suffix == "" and 0 <= a.value <= 3):
            raise err(f"argument {i + 1} of `mueller_entry`: expected an integer literal "
                      "0..3", a.loc)
    return c.finish(UNPOLARIZED)


def _reduce(c: _Call, b: Builtin) -> Type | None:
    c.nargs(1)
    if c.types[0] != UNPOLARIZED:
        c.arg(0, SPECTRUM)
    return c.finish(F32)


def _ray(c: _Call, b: Builtin) -> Type | None:
    c.nargs(1)
    c.arg(0, c.structs.get("Ray") or StructType("Ray"))
    result = c.structs.get(b.result) if isinstance(b.result, str) else b.result
    return c.finish(result)


_RULES: dict[Sig, Callable[[_Call, Builtin], Type | None]] = {
    Sig.FIXED: _fixed,
    Sig.FLOAT_MAP: _float_map,
    Sig.NUMBER_MAP: _float_map,
    Sig.MIN_MAX: _min_max,
    Sig.SELECT: _select,
    Sig.CONVERT: _convert,
    Sig.CONSTRUCT: _construct,
    Sig.SPECTRUM: _spectrum,
    Sig.ILLUMINANT: _illuminant,
    Sig.MUELLER: _mueller,
    Sig.MUELLER_ENTRY: _mueller_entry,
    Sig.REDUCE: _reduce,
    Sig.RAY: _ray,
}


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
