"""The C-like printer shared by the SIMD C backend (``c.py``) and OpenCL C (``opencl.py``).

It prints the body of one kernel, post-vectorize scalar IR, as C statements: one variable
per SSA value (``T vN = expr;``), structured ``if`` as C ``if``/``else`` assigning the
results declared before it, ``loop`` as ``for (;;)`` over the carried variables.  Uniform
values (``lanes == 1``) are plain C scalars with the semantics of ``docs/ir.md``; the
rendering of each op is one method in the dispatch table :data:`RENDER`, keyed by
:class:`ir.Op`, in the manner of tinygrad's ``CStyleLanguage``.  A subclass overrides what
its dialect spells differently: :class:`rdsl.compiler.backends.c.SimdC` the varying values
(GCC/Clang vector extensions), an OpenCL printer its vector types and built-ins.

Uniform bools are ``int`` 0/1.  Signed integer arithmetic is done on the unsigned type and
converted back (two's complement wrap, never C's undefined overflow); integer division and
remainder are guarded as in the IR (by 0 gives 0, ``INT_MIN / -1`` wraps).  Every float
operation is one C operation per statement, so nothing is contracted into FMA by a compiler
following ``-ffp-contract=on`` or ``off`` (``c.py`` asks for ``off``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from .. import ir
from ..diagnostics import CompileError

SCALAR_C = {"f32": "float", "i32": "int32_t", "u32": "uint32_t", "u64": "uint64_t",
            "bool": "int"}
MEM_C = {"f32": "float", "i32": "int32_t", "u32": "uint32_t", "u64": "uint64_t",
         "bool": "uint8_t"}
UNSIGNED = {"i32": "u32", "u32": "u32", "u64": "u64"}


def f32_literal(value: Any) -> str:
    """An exact C literal of the f32 nearest ``value`` (hex float; INFINITY, NAN)."""
    with np.errstate(over="ignore"):
        x = float(np.float32(value))
    if math.isnan(x):
        return "NAN"
    if x in (float("inf"), float("-inf")):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    s = x.hex() + "f"
    return f"({s})" if s.startswith("-") else s


def int_literal(value: Any, dtype: str) -> str:
    """A C literal of an integer constant wrapped to ``dtype``."""
    bits = 64 if dtype == "u64" else 32
    v = int(value) & ((1 << bits) - 1)
    if dtype == "i32":
        if v >= 1 << 31:
            v -= 1 << 32
        return "(-2147483647 - 1)" if v == -(1 << 31) else (f"({v})" if v < 0 else str(v))
    return f"{v}u" if dtype == "u32" else f"{v}ull"


def table_decls(tables: dict[str, list[float]], qualifier: str) -> list[str]:
    """File-scope declarations of read-only f32 tables (``qualifier``: ``static const`` in
    C, ``__constant`` in OpenCL C)."""
    out = []
    for name, values in tables.items():
        out.append(f"{qualifier} float {name}[{len(values)}] = {{")
        for k in range(0, len(values), 6):
            out.append("    " + ", ".join(f32_literal(v) for v in values[k:k + 6]) + ",")
        out.append("};")
    return out


class CLikePrinter:
    """Prints one kernel body.  ``names`` maps the function's params (and anything bound by
    the caller) to C expressions; :meth:`block` appends C lines to ``self.lines``."""

    width: ClassVar[int] = 1
    target_name: ClassVar[str] = "c"

    def __init__(self, names: dict[ir.Value, str], indent: int = 1,
                 on_return: Callable[[list[str]], None] | None = None) -> None:
        self.names = dict(names)
        self.lines: list[str] = []
        self.depth = indent
        self.counter = 0
        self.on_return = on_return
        self.tables: dict[str, list[float]] = {}  # C name -> values (file-scope arrays)
        self.used: set[ir.Value] = set()

    # -- output -------------------------------------------------------------------------
    def line(self, text: str) -> None:
        self.lines.append("    " * self.depth + text)

    def fresh(self) -> str:
        self.counter += 1
        return f"v{self.counter}"

    def v(self, value: ir.Value) -> str:
        try:
            return self.names[value]
        except KeyError:
            raise CompileError(f"{self.target_name} backend: use of undefined value "
                               f"{value!r}") from None

    # -- types --------------------------------------------------------------------------
    def ctype(self, t: ir.Type) -> str:
        """The C type of a value."""
        if not isinstance(t, ir.ScalarType):
            raise CompileError(f"the {self.target_name} backend sees scalars only, got {t}")
        return SCALAR_C[t.name] if t.lanes == 1 else self.vtype(t.name)

    def vtype(self, dtype: str) -> str:
        raise CompileError(f"the {self.target_name} printer has no vector types")

    def zero(self, t: ir.ScalarType) -> str:
        return "0" if t.lanes == 1 else "{0}"

    def splat(self, t: ir.ScalarType, scalar: str) -> str:
        """A value of type ``t`` with ``scalar`` (a C scalar expression) in every lane."""
        return scalar

    # -- declarations ---------------------------------------------------------------------
    def declare(self, value: ir.Value, expr: str | None) -> str:
        name = self.fresh()
        t = value.type
        init = expr if expr is not None else self.zero(t)
        self.line(f"{self.ctype(t)} {name} = {init};")
        if value not in self.used:
            self.line(f"(void){name};")
        self.names[value] = name
        return name

    def collect_uses(self, blk: ir.Block) -> None:
        for ins in blk.walk():
            self.used.update(ins.operands)

    # -- blocks -------------------------------------------------------------------------
    def block(self, blk: ir.Block) -> list[str] | None:
        """Print ``blk``; return the C expressions its ``yield`` passes on."""
        for ins in blk.instrs:
            if ins.op is ir.Op.YIELD:
                return [self.v(o) for o in ins.operands]
            if ins.op is ir.Op.RETURN:
                if self.on_return is None:
                    raise CompileError("unexpected `return`", ins.loc)
                self.on_return([self.v(o) for o in ins.operands])
                return None
            method = RENDER.get(ins.op)
            if method is None:
                self.unsupported(ins)
            out = getattr(self, method)(ins)
            if out is None:
                continue
            if isinstance(out, str):
                self.declare(ins.result, out)
        return []

    def unsupported(self, ins: ir.Instr) -> None:
        raise CompileError(f"the {self.target_name} backend cannot lower `{ins.op.value}` "
                           "(it must be removed by an earlier pass)", ins.loc)

    def render_if(self, ins: ir.Instr) -> None:
        outs = [self.declare(r, None) for r in ins.results]
        self.line(f"if ({self.v(ins.operands[0])}) {{")
        for k, region in enumerate(ins.regions):
            if k == 1:
                self.line("} else {")
            self.depth += 1
            vals = self.block(region) or []
            for o, val in zip(outs, vals):
                self.line(f"{o} = {val};")
            self.depth -= 1
        self.line("}")

    def render_loop(self, ins: ir.Instr) -> None:
        (body,) = ins.regions
        carried = []
        for arg, init in zip(body.args, ins.operands):
            self.used.add(arg)  # assigned every trip: never "unused"
            carried.append(self.declare(arg, self.v(init)))
        self.line("for (;;) {")
        self.depth += 1
        vals = self.block(body) or []
        cont, nxt = vals[0], vals[1:]
        # through temporaries: a yielded value may be another carried variable
        temps = []
        for arg, val in zip(body.args, nxt):
            t = self.fresh()
            self.line(f"{self.ctype(arg.type)} {t} = {val};")
            temps.append(t)
        for c, t in zip(carried, temps):
            self.line(f"{c} = {t};")
        self.line(f"if (!{cont}) break;")
        self.depth -= 1
        self.line("}")
        for r, c in zip(ins.results, carried):
            self.names[r] = c

    # -- scalar (uniform) semantics, overridden for varying values -------------------------
    def operands(self, ins: ir.Instr) -> list[str]:
        return [self.v(o) for o in ins.operands]

    @staticmethod
    def elem(ins: ir.Instr, k: int = 0) -> ir.ScalarType:
        t = ins.operands[k].type
        assert isinstance(t, ir.ScalarType), t
        return t

    def render_const(self, ins: ir.Instr) -> str:
        t = ins.type
        assert isinstance(t, ir.ScalarType)
        value = ins.attrs["value"]
        if t.name == "f32":
            c = f32_literal(value)
        elif t.name == "bool":
            c = ("-1" if t.lanes > 1 else "1") if value else "0"
        else:
            c = int_literal(value, t.name)
        return self.splat(t, c)

    def wrapping(self, t: ir.ScalarType, op: str, a: str, b: str | None = None) -> str:
        """``a op b`` (or ``op a``) with two's complement wrap for i32."""
        if t.name != "i32":
            return f"({op}{a})" if b is None else f"({a} {op} {b})"
        u = self.ctype(ir.ScalarType("u32", lanes=t.lanes))
        ua = self.reinterpret(u, a)
        r = f"({op}{ua})" if b is None else f"({ua} {op} {self.reinterpret(u, b)})"
        return self.reinterpret(self.ctype(t), r)

    def reinterpret(self, ctype: str, expr: str) -> str:
        """``expr`` as C type ``ctype`` of the same size, bit for bit (a C cast: vector
        extensions cast vectors bitwise, and i32 <-> u32 wraps)."""
        return f"(({ctype}){expr})"

    def render_arith(self, ins: ir.Instr) -> str:
        a, b = self.operands(ins)
        op = {ir.Op.ADD: "+", ir.Op.SUB: "-", ir.Op.MUL: "*"}[ins.op]
        t = self.elem(ins)
        return f"({a} {op} {b})" if t.is_float else self.wrapping(t, op, a, b)

    def render_bitwise(self, ins: ir.Instr) -> str:
        a, b = self.operands(ins)
        op = {ir.Op.AND: "&", ir.Op.OR: "|", ir.Op.XOR: "^"}[ins.op]
        return f"({a} {op} {b})"

    def render_neg(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        (a,) = self.operands(ins)
        return f"(-{a})" if t.is_float else self.wrapping(t, "-", a)

    def render_not(self, ins: ir.Instr) -> str:
        (a,) = self.operands(ins)
        t = self.elem(ins)
        return f"(!{a})" if t.name == "bool" and t.lanes == 1 else f"(~{a})"

    def render_shift(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        a, s = self.operands(ins)
        amount = f"({s} & {t.bits - 1})"
        if ins.op is ir.Op.SHR:
            return f"({a} >> {amount})"  # arithmetic on signed types (GCC, Clang)
        return self.wrapping(t, "<<", a, amount)

    def render_divrem(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        a, b = self.operands(ins)
        div = ins.op is ir.Op.DIV
        if t.is_float:
            return f"({a} / {b})" if div else f"fmodf({a}, {b})"
        guarded = f"({a} / {b})" if div else f"({a} % {b})"
        if t.is_signed:  # INT_MIN / -1 = INT_MIN, INT_MIN % -1 = 0
            ovf = f"({a} == (-2147483647 - 1) && {b} == -1)"
            guarded = f"({ovf} ? {a if div else '0'} : {guarded})"
        return f"({b} == 0 ? 0 : {guarded})"

    _CMP: ClassVar[dict[ir.Op, str]] = {ir.Op.EQ: "==", ir.Op.NE: "!=", ir.Op.LT: "<",
                                        ir.Op.LE: "<=", ir.Op.GT: ">", ir.Op.GE: ">="}

    def render_cmp(self, ins: ir.Instr) -> str:
        a, b = self.operands(ins)
        return f"({a} {self._CMP[ins.op]} {b})"  # C's float != is unordered, as the IR's

    def select(self, t: ir.ScalarType, cond: ir.Value, a: str, b: str) -> str:
        return f"({self.v(cond)} ? {a} : {b})"

    def render_select(self, ins: ir.Instr) -> str:
        c, a, b = ins.operands
        return self.select(ins.type, c, self.v(a), self.v(b))

    def render_minmax(self, ins: ir.Instr) -> str:
        a, b = self.operands(ins)
        op = "<" if ins.op is ir.Op.MIN else ">"
        return self.select_cmp(ins.type, f"({a} {op} {b})", a, b)

    def select_cmp(self, t: ir.ScalarType, cond: str, a: str, b: str) -> str:
        """select(cond, a, b) for a condition spelled as a C comparison of ``t`` values."""
        return f"({cond} ? {a} : {b})"

    def render_math(self, ins: ir.Instr) -> str | None:
        (a,) = self.operands(ins)
        return f"{ins.op.value}f({a})"  # sqrtf floorf ceilf: exactly rounded

    def render_abs(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        (a,) = self.operands(ins)
        if t.is_float:
            return f"fabsf({a})"
        if t.is_signed:
            return f"({a} < 0 ? {self.wrapping(t, '-', a)} : {a})"
        return a

    def render_cast(self, ins: ir.Instr) -> str:
        src, dst = self.elem(ins), ins.type
        assert isinstance(dst, ir.ScalarType)
        (a,) = self.operands(ins)
        if src.name == dst.name:
            return a
        if dst.name == "bool":
            return f"({a} != 0)"
        if src.is_float and dst.is_int:
            return self.saturate(a, dst)
        if src.name == "i32" and dst.name == "u64":
            return f"((uint64_t)(int64_t){a})"
        return f"(({SCALAR_C[dst.name]}){a})"

    def saturate(self, a: str, dst: ir.ScalarType) -> str:
        lo, below_hi, hi, top = saturation(dst)
        c = SCALAR_C[dst.name]
        return (f"({a} >= {hi} ? {top} : {a} > {below_hi} ? ({c}){below_hi} : "
                f"{a} < {lo} ? ({c}){lo} : {a} != {a} ? 0 : ({c}){a})")

    def render_bitcast(self, ins: ir.Instr) -> str:
        src, dst = self.elem(ins), ins.type
        (a,) = self.operands(ins)
        if src.name == dst.name:
            return a
        if src.is_float:
            return f"(({SCALAR_C[dst.name]})rdsl_f2u({a}))"
        if dst.is_float:
            return f"rdsl_u2f((uint32_t){a})"
        return f"(({SCALAR_C[dst.name]}){a})"

    def render_broadcast(self, ins: ir.Instr) -> str:
        (a,) = self.operands(ins)
        t = ins.type
        assert isinstance(t, ir.ScalarType)
        if t.lanes == 1 or self.elem(ins).lanes > 1:
            return a
        if t.name == "bool":
            a = f"-{a}"
        return self.splat(t, a)

    def render_any(self, ins: ir.Instr) -> str | None:
        (a,) = self.operands(ins)
        return a

    def render_lane(self, ins: ir.Instr) -> str:
        return "0"

    def render_table(self, ins: ir.Instr) -> None:
        import hashlib

        values = [float(np.float32(v)) for v in ins.attrs["values"]]
        digest = hashlib.sha1(np.asarray(values, np.float32).tobytes()).hexdigest()[:16]
        name = "rdsl_table_" + digest
        self.tables[name] = values
        self.names[ins.result] = name

    def mem_to_value(self, e: str, expr: str, lanes: int) -> str:
        if e != "bool":
            return expr
        return f"-({expr} != 0)" if lanes > 1 else f"({expr} != 0)"

    def render_load(self, ins: ir.Instr) -> str:
        buf, idx = ins.operands
        e = buf.type.elem.name  # type: ignore[attr-defined]
        return self.mem_to_value(e, f"{self.v(buf)}[{self.v(idx)}]", 1)

    def render_store(self, ins: ir.Instr) -> None:
        buf, idx, val = ins.operands
        e = buf.type.elem.name  # type: ignore[attr-defined]
        v = self.v(val)
        if e == "bool":
            v = f"(uint8_t)({v} != 0)"
        self.line(f"{self.v(buf)}[{self.v(idx)}] = {v};")

    def render_gather(self, ins: ir.Instr) -> str:
        buf, idx, mask = ins.operands
        e = buf.type.elem.name  # type: ignore[attr-defined]
        loaded = self.mem_to_value(e, f"{self.v(buf)}[{self.v(idx)}]", 1)
        return f"({self.v(mask)} ? {loaded} : 0)"

    def render_scatter(self, ins: ir.Instr) -> None:
        buf, idx, val, mask = ins.operands
        e = buf.type.elem.name  # type: ignore[attr-defined]
        v = self.v(val)
        if e == "bool":
            v = f"(uint8_t)({v} != 0)"
        self.line(f"if ({self.v(mask)}) {self.v(buf)}[{self.v(idx)}] = {v};")

    def render_ray(self, ins: ir.Instr) -> None:
        what = "trace" if ins.op is ir.Op.INTERSECT else "occluded"
        raise NoRayTracer(f"the {self.target_name} backend cannot trace rays: `{what}` (IR "
                           f"`{ins.op.value}`) needs Embree, which only the LLVM CPU targets "
                           "link (a BVH written in rdsl is not there yet); compile this "
                           "kernel for scalar, sse4, avx2 or avx512", ins.loc)


class NoRayTracer(CompileError):
    """A kernel traces rays on a target that has no ray tracer (no Embree; no BVH in rdsl)."""


def saturation(dst: ir.ScalarType) -> tuple[str, str, str, str]:
    """C literals of the clamp of a saturating f32 -> ``dst`` conversion: the lowest value,
    the largest f32 below the top of the range, the top of the range as f32, and the
    largest value of ``dst``."""
    lo = -(2.0 ** (dst.bits - 1)) if dst.is_signed else 0.0
    hi = 2.0 ** (dst.bits - 1) if dst.is_signed else 2.0 ** dst.bits
    top = (1 << (dst.bits - 1)) - 1 if dst.is_signed else (1 << dst.bits) - 1
    return (f32_literal(lo), f32_literal(hi * (1.0 - 2.0 ** -24)), f32_literal(hi),
            int_literal(top, dst.name))


RENDER: dict[ir.Op, str] = {  # op -> the printer method that renders it
    ir.Op.CONST: "render_const",
    ir.Op.ADD: "render_arith",
    ir.Op.SUB: "render_arith",
    ir.Op.MUL: "render_arith",
    ir.Op.DIV: "render_divrem",
    ir.Op.REM: "render_divrem",
    ir.Op.NEG: "render_neg",
    ir.Op.AND: "render_bitwise",
    ir.Op.OR: "render_bitwise",
    ir.Op.XOR: "render_bitwise",
    ir.Op.NOT: "render_not",
    ir.Op.SHL: "render_shift",
    ir.Op.SHR: "render_shift",
    **{op: "render_cmp" for op in ir.CMP_OPS},
    ir.Op.SELECT: "render_select",
    ir.Op.SQRT: "render_math",
    ir.Op.FLOOR: "render_math",
    ir.Op.CEIL: "render_math",
    ir.Op.ABS: "render_abs",
    ir.Op.MIN: "render_minmax",
    ir.Op.MAX: "render_minmax",
    ir.Op.CAST: "render_cast",
    ir.Op.BITCAST: "render_bitcast",
    ir.Op.BROADCAST: "render_broadcast",
    ir.Op.ANY: "render_any",
    ir.Op.LANE: "render_lane",
    ir.Op.TABLE: "render_table",
    ir.Op.LOAD: "render_load",
    ir.Op.STORE: "render_store",
    ir.Op.GATHER: "render_gather",
    ir.Op.SCATTER: "render_scatter",
    ir.Op.IF: "render_if",
    ir.Op.LOOP: "render_loop",
    ir.Op.INTERSECT: "render_ray",
    ir.Op.OCCLUDED: "render_ray",
}
