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
from collections.abc import Sequence
from typing import Any

import numpy as np

from .ir import (
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


def _f32_unary(op: Op, a: np.float32) -> Any:
    if op is Op.NEG:
        return bits_f32(f32_bits(a) ^ 0x8000_0000)
    if op is Op.ABS:
        return bits_f32(f32_bits(a) & 0x7FFF_FFFF)
    if op is Op.SQRT:
        return np.sqrt(a)
    if op is Op.FLOOR:
        return np.floor(a)
    if op is Op.CEIL:
        return np.ceil(a)
    raise InterpError(f"'{op.value}' is not defined on f32")


def _f32_binary(op: Op, a: np.float32, b: np.float32) -> Any:
    if op is Op.ADD:
        return a + b
    if op is Op.SUB:
        return a - b
    if op is Op.MUL:
        return a * b
    if op is Op.DIV:
        return a / b
    if op is Op.REM:
        return np.fmod(a, b)
    if op is Op.MIN:
        return a if a < b else b  # noqa: FURB136 -- select(a < b, a, b)
    if op is Op.MAX:
        return a if a > b else b  # noqa: FURB136 -- select(a > b, a, b)
    raise InterpError(f"'{op.value}' is not defined on f32")


def _int_unary(op: Op, name: str, a: int) -> Any:
    if op is Op.NEG:
        return wrap_int(-a, name)
    if op is Op.NOT:
        return wrap_int(~a, name)
    if op is Op.ABS:
        return wrap_int(abs(a), name)
    raise InterpError(f"'{op.value}' is not defined on {name}")


def _int_binary(op: Op, name: str, a: int, b: int) -> Any:
    bits = 64 if name == "u64" else 32
    if op is Op.ADD:
        r = a + b
    elif op is Op.SUB:
        r = a - b
    elif op is Op.MUL:
        r = a * b
    elif op in (Op.DIV, Op.REM):
        if b == 0:
            r = 0
        else:
            q = abs(a) // abs(b)  # truncate toward zero
            if (a < 0) != (b < 0):
                q = -q
            r = q if op is Op.DIV else a - b * q
    elif op is Op.AND:
        r = a & b
    elif op is Op.OR:
        r = a | b
    elif op is Op.XOR:
        r = a ^ b
    elif op is Op.SHL:
        r = a << (b % bits)
    elif op is Op.SHR:
        r = a >> (b % bits)  # a is signed for i32 (arithmetic), non-negative otherwise
    elif op is Op.MIN:
        r = a if a < b else b  # noqa: FURB136
    elif op is Op.MAX:
        r = a if a > b else b  # noqa: FURB136
    else:
        raise InterpError(f"'{op.value}' is not defined on {name}")
    return wrap_int(r, name)


def _bool_op(op: Op, a: bool, b: bool | None = None) -> bool:
    if op is Op.NOT:
        return not a
    if op is Op.AND:
        return a and b
    if op is Op.OR:
        return a or b
    if op is Op.XOR:
        return a != b
    if op is Op.MIN:
        return a if a < b else b  # noqa: FURB136 -- select(a < b, a, b)
    if op is Op.MAX:
        return a if a > b else b  # noqa: FURB136 -- select(a > b, a, b)
    raise InterpError(f"'{op.value}' is not defined on bool")


def _compare(op: Op, a: Any, b: Any) -> bool:
    # numpy float32 comparisons are IEEE: ordered, except != which is unordered
    if op is Op.EQ:
        return bool(a == b)
    if op is Op.NE:
        return bool(a != b)
    if op is Op.LT:
        return bool(a < b)
    if op is Op.LE:
        return bool(a <= b)
    if op is Op.GT:
        return bool(a > b)
    return bool(a >= b)


def _elementwise(op: Op, t: Type, args: Sequence[Any]) -> Any:
    if isinstance(t, SpectrumType):
        raise InterpError("spectrum values are not supported by the interpreter; run lift first")
    if not isinstance(t, ScalarType):
        comps = components(t)
        return tuple(_elementwise(op, ct, [a[i] for a in args]) for i, ct in enumerate(comps))
    if t.name == "f32":
        fargs = [np.float32(a) for a in args]
        return _f32_unary(op, *fargs) if len(fargs) == 1 else _f32_binary(op, *fargs)
    if t.name == "bool":
        return _bool_op(op, *[bool(a) for a in args])
    iargs = [int(a) for a in args]
    return _int_unary(op, t.name, *iargs) if len(iargs) == 1 else _int_binary(op, t.name, *iargs)


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


def eval_pure(op: Op, result_type: Type, operand_types: Sequence[Type], args: Sequence[Any],
              attrs: dict[str, Any]) -> Any:
    """Evaluate one pure single-result op on interpreter values.  Raises InterpError if the
    op is not supported here."""
    if op is Op.CONST:
        if "value" not in attrs:
            raise InterpError(f"constant {attrs} has no value (unresolved trait?)")
        return coerce(attrs["value"], result_type)
    if op in (Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.REM, Op.NEG, Op.AND, Op.OR, Op.XOR, Op.NOT,
              Op.SHL, Op.SHR, Op.SQRT, Op.FLOOR, Op.CEIL, Op.ABS, Op.MIN, Op.MAX):
        return _elementwise(op, operand_types[0], args)
    if op in (Op.EQ, Op.NE, Op.LT, Op.LE, Op.GT, Op.GE):
        if not isinstance(operand_types[0], ScalarType):
            raise InterpError(f"'{op.value}' is defined on scalars only")
        return _compare(op, args[0], args[1])
    if op is Op.SELECT:
        return args[1] if args[0] else args[2]
    if op in (Op.CAST, Op.BITCAST):
        src, dst = operand_types[0], result_type
        if not (isinstance(src, ScalarType) and isinstance(dst, ScalarType)):
            raise InterpError(f"'{op.value}' from {src} to {dst} is not supported")
        fn = cast_scalar if op is Op.CAST else bitcast_scalar
        return fn(args[0], src, dst)
    if op is Op.MAKE:
        if isinstance(result_type, SpectrumType):
            raise InterpError("spectrum values are not supported; run lift first")
        return tuple(args)
    if op is Op.EXTRACT:
        return args[0][attrs["index"]]
    if op is Op.INSERT:
        i = attrs["index"]
        agg = args[0]
        return agg[:i] + (args[1],) + agg[i + 1:]
    if op is Op.BROADCAST:
        return _broadcast(args[0], result_type)
    if op is Op.LANE:
        return np.int32(0)
    if op is Op.ANY:
        return bool(args[0])
    raise InterpError(f"'{op.value}' is not supported by the interpreter")


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
