"""The reference interpreter: the ground truth of the differential tests.

It executes one lane of a function with the *exact* scalar semantics of ``docs/ir.md``:
``f32`` values are ``numpy.float32`` scalars and every float operation is done in float32
(never in Python's f64); integers are computed with Python ints and wrapped to their width
(``numpy.int32`` / ``uint32`` / ``uint64``); ``bool`` is a Python ``bool``.  Aggregates are
tuples of their components (nested), buffers are numpy arrays (``store`` mutates them).

:func:`eval_pure` is the one implementation of every pure op; ``passes/optimize.py`` folds
constants with it, so the optimizer and the interpreter can never disagree.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .builtins import F32_INTRINSICS
from .ir import (
    CMP_OPS,
    ELEMENTWISE_OPS,
    Block,
    BufferType,
    Function,
    Instr,
    MatType,
    Module,
    Op,
    ScalarType,
    SpectrumType,
    Type,
    VecType,
    components,
)

STEP_LIMIT = 10_000_000


class InterpError(RuntimeError):
    """The interpreter cannot run this IR (unsupported op, bad argument, ...)."""


class StepLimitExceeded(InterpError):
    """More than the step limit of instructions executed (probably an infinite loop)."""


# --------------------------------------------------------------------------------------
# Scalars

_INT_RANGE = {
    "i32": (-(1 << 31), (1 << 31) - 1),
    "u32": (0, (1 << 32) - 1),
    "u64": (0, (1 << 64) - 1),
}
_NP_INT = {"i32": np.int32, "u32": np.uint32, "u64": np.uint64}
_SIGN32 = np.uint32(0x8000_0000)


def wrap_int(x: int, name: str) -> Any:
    """Wrap a Python int to the two's complement range of ``name`` as a numpy scalar."""
    if name == "i32":
        x = ((x + (1 << 31)) & 0xFFFF_FFFF) - (1 << 31)
    elif name == "u32":
        x &= 0xFFFF_FFFF
    else:
        x &= 0xFFFF_FFFF_FFFF_FFFF
    return _NP_INT[name](x)


def int_to_f32(x: int) -> np.float32:
    """Round an integer to the nearest f32 (ties to even) with a single rounding."""
    mag = abs(x)
    n = mag.bit_length()
    if n > 24:
        shift = n - 24
        q, r = mag >> shift, mag & ((1 << shift) - 1)
        half = 1 << (shift - 1)
        if r > half or (r == half and q & 1):
            q += 1
        mag = q << shift  # at most 25 significant bits: exact in f64 and f32 range
    return np.float32(float(-mag if x < 0 else mag))


def f32_bits(x: Any) -> int:
    return int(np.float32(x).view(np.uint32))


def bits_f32(b: int) -> np.float32:
    return np.uint32(b & 0xFFFF_FFFF).view(np.float32)


def coerce(value: Any, t: Type) -> Any:
    """Convert a Python/numpy value (or nested tuple) to the interpreter's representation."""
    if isinstance(t, ScalarType):
        if t.name == "bool":
            return bool(value)
        if t.name == "f32":
            if isinstance(value, (bool, np.bool_)):
                return np.float32(1.0 if value else 0.0)
            if isinstance(value, (int, np.integer)):
                return int_to_f32(int(value))
            return np.float32(value)
        if isinstance(value, (float, np.floating)) and not float(value).is_integer():
            raise InterpError(f"{value!r} is not a valid {t.name}")
        return wrap_int(int(value), t.name)
    if isinstance(t, BufferType):
        if not isinstance(value, np.ndarray):
            raise InterpError(f"a {t} argument must be a numpy array, got {type(value).__name__}")
        return value
    if isinstance(t, SpectrumType):
        raise InterpError("spectrum values are not supported by the interpreter; run lift first")
    comps = components(t)
    if not isinstance(value, (tuple, list, np.ndarray)) or len(value) != len(comps):
        raise InterpError(f"a {t} value must be a tuple of {len(comps)} components")
    return tuple(coerce(v, ct) for v, ct in zip(value, comps))


# One table per operand kind, keyed by op: the exact scalar semantics of each op.

_F32_UNARY: dict[Op, Callable[[np.float32], Any]] = {
    Op.NEG: lambda a: bits_f32(f32_bits(a) ^ 0x8000_0000),
    Op.ABS: lambda a: bits_f32(f32_bits(a) & 0x7FFF_FFFF),
    **{op: i.f32 for op, i in F32_INTRINSICS.items()},
}

_F32_BINARY: dict[Op, Callable[[np.float32, np.float32], Any]] = {
    Op.ADD: lambda a, b: a + b,
    Op.SUB: lambda a, b: a - b,
    Op.MUL: lambda a, b: a * b,
    Op.DIV: lambda a, b: a / b,
    Op.REM: np.fmod,
    Op.MIN: lambda a, b: a if a < b else b,  # noqa: FURB136 -- select(a < b, a, b)
    Op.MAX: lambda a, b: a if a > b else b,  # noqa: FURB136 -- select(a > b, a, b)
}

_INT_UNARY: dict[Op, Callable[[int], int]] = {
    Op.NEG: lambda a: -a,
    Op.NOT: lambda a: ~a,
    Op.ABS: abs,
}


def _int_divrem(op: Op, a: int, b: int) -> int:
    if b == 0:
        return 0
    q = abs(a) // abs(b)  # truncate toward zero
    if (a < 0) != (b < 0):
        q = -q
    return q if op is Op.DIV else a - b * q


# (a, b, bit width) -> the unwrapped result; the shift amount is taken modulo the width and
# `>>` is arithmetic for i32 because a is then signed (non-negative otherwise)
_INT_BINARY: dict[Op, Callable[[int, int, int], int]] = {
    Op.ADD: lambda a, b, bits: a + b,
    Op.SUB: lambda a, b, bits: a - b,
    Op.MUL: lambda a, b, bits: a * b,
    Op.DIV: lambda a, b, bits: _int_divrem(Op.DIV, a, b),
    Op.REM: lambda a, b, bits: _int_divrem(Op.REM, a, b),
    Op.AND: lambda a, b, bits: a & b,
    Op.OR: lambda a, b, bits: a | b,
    Op.XOR: lambda a, b, bits: a ^ b,
    Op.SHL: lambda a, b, bits: a << (b % bits),
    Op.SHR: lambda a, b, bits: a >> (b % bits),
    Op.MIN: lambda a, b, bits: a if a < b else b,  # noqa: FURB136
    Op.MAX: lambda a, b, bits: a if a > b else b,  # noqa: FURB136
}

_BOOL_UNARY: dict[Op, Callable[[bool], bool]] = {Op.NOT: lambda a: not a}

_BOOL_BINARY: dict[Op, Callable[[bool, bool], bool]] = {
    Op.AND: lambda a, b: a and b,
    Op.OR: lambda a, b: a or b,
    Op.XOR: lambda a, b: a != b,
    Op.MIN: lambda a, b: a if a < b else b,  # noqa: FURB136 -- select(a < b, a, b)
    Op.MAX: lambda a, b: a if a > b else b,  # noqa: FURB136 -- select(a > b, a, b)
}

# numpy float32 comparisons are IEEE: ordered, except != which is unordered
_COMPARE: dict[Op, Callable[[Any, Any], Any]] = {
    Op.EQ: lambda a, b: a == b,
    Op.NE: lambda a, b: a != b,
    Op.LT: lambda a, b: a < b,
    Op.LE: lambda a, b: a <= b,
    Op.GT: lambda a, b: a > b,
    Op.GE: lambda a, b: a >= b,
}


def _rule(table: dict[Op, Callable[..., Any]], op: Op, name: str) -> Callable[..., Any]:
    rule = table.get(op)
    if rule is None:
        raise InterpError(f"'{op.value}' is not defined on {name}")
    return rule


def _elementwise(op: Op, t: Type, args: Sequence[Any]) -> Any:
    if isinstance(t, SpectrumType):
        raise InterpError("spectrum values are not supported by the interpreter; run lift first")
    if not isinstance(t, ScalarType):
        comps = components(t)
        return tuple(_elementwise(op, ct, [a[i] for a in args]) for i, ct in enumerate(comps))
    unary = len(args) == 1
    if t.name == "f32":
        return _rule(_F32_UNARY if unary else _F32_BINARY, op, "f32")(
            *[np.float32(a) for a in args])
    if t.name == "bool":
        return _rule(_BOOL_UNARY if unary else _BOOL_BINARY, op, "bool")(
            *[bool(a) for a in args])
    iargs = [int(a) for a in args]
    if unary:
        return wrap_int(_rule(_INT_UNARY, op, t.name)(*iargs), t.name)
    bits = 64 if t.name == "u64" else 32
    return wrap_int(_rule(_INT_BINARY, op, t.name)(*iargs, bits), t.name)


def cast_scalar(a: Any, src: ScalarType, dst: ScalarType) -> Any:
    """``cast`` between scalar types (see docs/ir.md)."""
    if dst.name == "bool":
        return bool(a != 0)
    if src.name == "bool":
        return coerce(1 if a else 0, dst)
    if dst.name == "f32":
        return np.float32(a) if src.name == "f32" else int_to_f32(int(a))
    if src.name == "f32":
        x = float(a)
        lo, hi = _INT_RANGE[dst.name]
        if math.isnan(x):
            return _NP_INT[dst.name](0)
        if math.isinf(x):
            return _NP_INT[dst.name](hi if x > 0 else lo)
        return _NP_INT[dst.name](min(max(math.trunc(x), lo), hi))
    return wrap_int(int(a), dst.name)


def bitcast_scalar(a: Any, src: ScalarType, dst: ScalarType) -> Any:
    if src.name == "f32":
        bits = f32_bits(a)
    elif src.name == "bool":
        bits = int(bool(a))
    else:
        bits = int(a)
    if dst.name == "f32":
        return bits_f32(bits)
    if dst.name == "bool":
        return bool(bits & 1)
    return wrap_int(bits, dst.name)


def _broadcast(a: Any, t: Type) -> Any:
    if isinstance(t, (VecType, MatType)):
        return tuple(_broadcast(a, ct) for ct in components(t))
    if isinstance(t, SpectrumType):
        raise InterpError("spectrum values are not supported by the interpreter; run lift first")
    return a


# (result type, operand types, operand values, attributes) -> the result
_PureRule = Callable[[Type, Sequence[Type], Sequence[Any], dict[str, Any]], Any]


def _const(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
    if "value" not in attrs:
        raise InterpError(f"constant {attrs} has no value (unresolved trait?)")
    return coerce(attrs["value"], rt)


def _elementwise_op(op: Op) -> _PureRule:
    def rule(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
        return _elementwise(op, ts[0], args)
    return rule


def _compare_op(op: Op) -> _PureRule:
    def rule(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
        if not isinstance(ts[0], ScalarType):
            raise InterpError(f"'{op.value}' is defined on scalars only")
        return bool(_COMPARE[op](args[0], args[1]))
    return rule


def _conversion(op: Op, fn: Callable[[Any, ScalarType, ScalarType], Any]) -> _PureRule:
    def rule(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
        src, dst = ts[0], rt
        if not (isinstance(src, ScalarType) and isinstance(dst, ScalarType)):
            raise InterpError(f"'{op.value}' from {src} to {dst} is not supported")
        return fn(args[0], src, dst)
    return rule


def _make(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
    if isinstance(rt, SpectrumType):
        raise InterpError("spectrum values are not supported; run lift first")
    return tuple(args)


def _insert(rt: Type, ts: Sequence[Type], args: Sequence[Any], attrs: dict[str, Any]) -> Any:
    i = attrs["index"]
    agg = args[0]
    return agg[:i] + (args[1],) + agg[i + 1:]


def _zero(rt: Type) -> Any:
    """Zero of a float type (a scalar, or the tuple of a vector's components)."""
    n = len(components(rt)) if not isinstance(rt, ScalarType) else 0
    return np.float32(0.0) if n == 0 else tuple(np.float32(0.0) for _ in range(n))


_PURE: dict[Op, _PureRule] = {
    Op.CONST: _const,
    **{op: _elementwise_op(op) for op in ELEMENTWISE_OPS},
    **{op: _compare_op(op) for op in CMP_OPS},
    Op.SELECT: lambda rt, ts, args, attrs: args[1] if args[0] else args[2],
    Op.CAST: _conversion(Op.CAST, cast_scalar),
    Op.BITCAST: _conversion(Op.BITCAST, bitcast_scalar),
    Op.MAKE: _make,
    Op.EXTRACT: lambda rt, ts, args, attrs: args[0][attrs["index"]],
    Op.INSERT: _insert,
    Op.BROADCAST: lambda rt, ts, args, attrs: _broadcast(args[0], rt),
    Op.LANE: lambda rt, ts, args, attrs: np.int32(0),
    Op.ANY: lambda rt, ts, args, attrs: bool(args[0]),
    # automatic differentiation, as a build without AD computes it (ad_forward's contract)
    Op.DETACH: lambda rt, ts, args, attrs: args[0],
    Op.AD_RULE: lambda rt, ts, args, attrs: args[(len(args) - 1) // 2],
    Op.DERIV: lambda rt, ts, args, attrs: _zero(rt),
}


def eval_pure(op: Op, result_type: Type, operand_types: Sequence[Type], args: Sequence[Any],
              attrs: dict[str, Any]) -> Any:
    """Evaluate one pure single-result op on interpreter values.  Raises InterpError if the
    op is not supported here."""
    rule = _PURE.get(op)
    if rule is None:
        raise InterpError(f"'{op.value}' is not supported by the interpreter")
    return rule(result_type, operand_types, args, attrs)


# --------------------------------------------------------------------------------------
# Control flow


class _Interp:
    def __init__(self, module: Module, step_limit: int) -> None:
        self.module = module
        self.steps = 0
        self.step_limit = step_limit

    def call(self, fn: Function, args: Sequence[Any]) -> list[Any]:
        if len(args) != len(fn.params):
            raise InterpError(f"@{fn.name} takes {len(fn.params)} arguments, got {len(args)}")
        env = {p.value: coerce(a, p.value.type) for p, a in zip(fn.params, args)}
        return self.block(fn.body, env)

    def block(self, block: Block, env: dict) -> list[Any]:
        """Run a block; returns the operands of its terminator."""
        for ins in block.instrs:
            self.steps += 1
            if self.steps > self.step_limit:
                raise StepLimitExceeded(f"more than {self.step_limit} instructions executed")
            if ins.op in (Op.YIELD, Op.RETURN):
                return [env[v] for v in ins.operands]
            vals = self.instr(ins, [env[v] for v in ins.operands], env)
            for r, v in zip(ins.results, vals):
                env[r] = v
        raise InterpError("block without terminator")

    def instr(self, ins: Instr, args: list[Any], env: dict) -> list[Any]:
        op = ins.op
        if op is Op.IF:
            return self.block(ins.regions[0] if args[0] else ins.regions[1], env)
        if op is Op.LOOP:
            body = ins.regions[0]
            while True:
                for a, v in zip(body.args, args):
                    env[a] = v
                out = self.block(body, env)
                args = out[1:]
                if not out[0]:
                    return args
        if op is Op.TABLE:
            return [np.asarray(ins.attrs["values"], np.float32)]
        if op in (Op.LOAD, Op.GATHER):
            if op is Op.GATHER and not args[2]:
                return [coerce(0, ins.results[0].type)]
            buf, t = args[0], ins.results[0].type
            return [coerce(buf[int(args[1])].item(), t)]
        if op in (Op.STORE, Op.SCATTER):
            if op is Op.STORE or args[3]:
                args[0][int(args[1])] = args[2]
            return []
        if op is Op.CALL:
            callee = self.module.functions.get(ins.attrs.get("callee"))
            if callee is None:
                raise InterpError(f"call to unknown function @{ins.attrs.get('callee')}")
            return self.call(callee, args)
        if any(isinstance(t.type, SpectrumType) for t in ins.results):
            raise InterpError("spectrum values are not supported by the interpreter; run lift first")
        return [eval_pure(op, ins.results[0].type, [v.type for v in ins.operands], args,
                          ins.attrs)]


def run_function(module: Module, fn_name: str, args: Sequence[Any],
                 step_limit: int = STEP_LIMIT) -> list[Any]:
    """Run ``module.functions[fn_name]`` on one lane.  Scalars may be Python or numpy
    numbers, aggregates tuples, buffers numpy arrays (mutated by ``store``).  Returns the
    returned values (aggregates as tuples)."""
    fn = module.functions.get(fn_name)
    if fn is None:
        raise InterpError(f"no function @{fn_name}")
    with np.errstate(all="ignore"):
        return _Interp(module, step_limit).call(fn, args)


__all__ = [
    "STEP_LIMIT",
    "InterpError",
    "StepLimitExceeded",
    "bitcast_scalar",
    "bits_f32",
    "cast_scalar",
    "coerce",
    "eval_pure",
    "f32_bits",
    "int_to_f32",
    "run_function",
    "wrap_int",
]
