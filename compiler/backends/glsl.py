"""The GLSL 4.50 compute-shader backend (``--target spirv``): post-vectorize IR of width 1
-> one compute shader per kernel, compiled to SPIR-V by ``glslangValidator`` (see
``glsl_entry.py`` for the shader around the body and ``spirv_build.py`` for the build).

One invocation runs one element (one lane), so every value is a GLSL scalar: the printer is
:class:`~.c_like.CLikePrinter` with GLSL's spelling of what C spells differently.  Bools are
GLSL ``bool`` (``&&``, ``||``, ``^^``); conversions are constructors (``int(x)``); bit casts
are ``floatBitsToUint`` and friends; f32 constants are exact (a decimal literal that
round-trips, else ``uintBitsToFloat``).  Integer arithmetic in SPIR-V wraps, as the IR's does;
signed ``rem`` is spelled ``a - (a / b) * b`` (GLSL's ``%`` may be lowered to ``OpSMod``,
whose sign follows the divisor).  Float ``rem`` is C's ``fmodf``, exact: :data:`FMODF`, musl's
integer algorithm (``a - b * trunc(a / b)`` is not, once the quotient rounds).

64-bit integers (``UInt64``, which PCG32 uses) need ``GL_ARB_gpu_shader_int64`` and a device
with ``shaderInt64`` (lavapipe has it; the runtime says so where a device has not).  Float
values are declared ``precise``: no multiply-add of the IR is contracted into an FMA, so the
shader rounds where the IR does.  Vulkan allows ``sqrt`` and division a few ulps of error
(lavapipe's are exactly rounded in practice), and may flush denormals.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from .. import ir
from ..diagnostics import CompileError
from .base import Backend
from .c_like import CLikePrinter, int_literal

GLSL_TYPES = {"f32": "float", "i32": "int", "u32": "uint", "u64": "uint64_t", "bool": "bool"}
# how each dtype lies in a storage buffer (bools as 32-bit 0/1)
GLSL_MEM = {"f32": "float", "i32": "int", "u32": "uint", "u64": "uint64_t", "bool": "uint"}
_ZERO = {"f32": "0.0", "i32": "0", "u32": "0u", "u64": "0ul", "bool": "false"}


# C's fmodf in GLSL, exact: musl's fmodf (integer long division of the significands)
FMODF = """float rdsl_fmodf(float x, float y) {
    uint ux = floatBitsToUint(x), uy = floatBitsToUint(y);
    int ex = int(ux >> 23 & 0xffu), ey = int(uy >> 23 & 0xffu);
    uint sx = ux & 0x80000000u;
    if (uy << 1 == 0u || isnan(y) || ex == 0xff) return uintBitsToFloat(0x7fc00000u);
    if (ux << 1 <= uy << 1) return ux << 1 == uy << 1 ? uintBitsToFloat(sx) : x;
    uint i;
    if (ex == 0) {
        for (i = ux << 9; i >> 31 == 0u; ex--, i <<= 1) {}
        ux <<= uint(-ex + 1);
    } else {
        ux = (ux & 0x7fffffu) | 0x800000u;
    }
    if (ey == 0) {
        for (i = uy << 9; i >> 31 == 0u; ey--, i <<= 1) {}
        uy <<= uint(-ey + 1);
    } else {
        uy = (uy & 0x7fffffu) | 0x800000u;
    }
    for (; ex > ey; ex--) {
        i = ux - uy;
        if (i >> 31 == 0u) {
            if (i == 0u) return uintBitsToFloat(sx);
            ux = i;
        }
        ux <<= 1;
    }
    i = ux - uy;
    if (i >> 31 == 0u) {
        if (i == 0u) return uintBitsToFloat(sx);
        ux = i;
    }
    for (; ux >> 23 == 0u; ux <<= 1, ex--) {}
    if (ex > 0) {
        ux = (ux - 0x800000u) | (uint(ex) << 23);
    } else {
        ux >>= uint(-ex + 1);
    }
    return uintBitsToFloat(ux | sx);
}"""


class GlslBackend(Backend):
    """GLSL 4.50 compute shaders, one invocation per element, compiled to SPIR-V."""

    name = "spirv"
    emits = ("comp", "spv")
    supports_gather = True
    supports_scatter = True
    supports_float_rem = True
    max_width = 1
    widths = (1,)


def glsl_float(value: float) -> str:
    """An exact GLSL expression of the f32 nearest ``value``."""
    with np.errstate(over="ignore"):
        x = np.float32(value)
    bits = int(x.view(np.uint32))
    if math.isfinite(float(x)) and not (x == 0 and bits >> 31):
        if x == 0 or 1e-4 <= abs(x) < 1e8:
            text = np.format_float_positional(x, unique=True, trim="0")
        else:
            text = np.format_float_scientific(x, unique=True, trim="0").replace(".e", ".0e")
        # glslang reads a literal as a double and rounds it to float: check that path
        if np.float32(float(text)) == x:
            return f"({text})" if text.startswith("-") else text
    return f"uintBitsToFloat(0x{bits:08x}u)"


def glsl_int(value: int, dtype: str) -> str:
    """A GLSL literal of an integer constant wrapped to ``dtype``."""
    c = int_literal(value, dtype)
    return c[:-3] + "ul" if c.endswith("ull") else c


class GlslPrinter(CLikePrinter):
    """The C-like printer with GLSL's types, literals, conversions and built-ins."""

    target_name: ClassVar[str] = "spirv"

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.table_names: set[str] = set()
        self.pooled: dict[str, tuple[str, str]] = {}  # buffer name -> (pool, offset expr)
        self.uses_fmodf = False  # float rem: FMODF, defined before main

    def ctype(self, t: ir.Type) -> str:
        if not isinstance(t, ir.ScalarType) or t.lanes != 1:
            raise CompileError(f"the spirv backend sees scalars of width 1 only, got {t}")
        return GLSL_TYPES[t.name]

    def zero(self, t: ir.ScalarType) -> str:
        return _ZERO[t.name]

    def declare(self, value: ir.Value, expr: str | None) -> str:
        name = self.fresh()
        t = value.type
        assert isinstance(t, ir.ScalarType)
        init = expr if expr is not None else self.zero(t)
        precise = "precise " if t.name == "f32" else ""
        self.line(f"{precise}{self.ctype(t)} {name} = {init};")
        self.names[value] = name
        return name

    def render_const(self, ins: ir.Instr) -> str:
        t = ins.type
        assert isinstance(t, ir.ScalarType)
        value = ins.attrs["value"]
        if t.name == "f32":
            return glsl_float(value)
        if t.name == "bool":
            return "true" if value else "false"
        return glsl_int(value, t.name)

    def wrapping(self, t: ir.ScalarType, op: str, a: str, b: str | None = None) -> str:
        return f"({op}{a})" if b is None else f"({a} {op} {b})"  # SPIR-V integers wrap

    _LOGIC: ClassVar[dict[ir.Op, str]] = {ir.Op.AND: "&&", ir.Op.OR: "||", ir.Op.XOR: "^^"}

    def render_bitwise(self, ins: ir.Instr) -> str:
        if self.elem(ins).name != "bool":
            return super().render_bitwise(ins)
        a, b = self.operands(ins)
        return f"({a} {self._LOGIC[ins.op]} {b})"

    def render_shift(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        a, s = self.operands(ins)
        mask = glsl_int(t.bits - 1, self.elem(ins, 1).name)
        op = ">>" if ins.op is ir.Op.SHR else "<<"
        return f"({a} {op} ({s} & {mask}))"

    def render_divrem(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        a, b = self.operands(ins)
        div = ins.op is ir.Op.DIV
        if t.is_float:
            if div:
                return f"({a} / {b})"
            self.uses_fmodf = True
            return f"rdsl_fmodf({a}, {b})"
        z = _ZERO[t.name]
        if not t.is_signed:
            return f"({b} == {z} ? {z} : ({a} {'/' if div else '%'} {b}))"
        # by 0 gives 0; INT_MIN / -1 wraps to INT_MIN (divide by 1), INT_MIN % -1 is 0
        ovf = f"({a} == (-2147483647 - 1) && {b} == -1)"
        safe = f"(({b} == 0 || {ovf}) ? 1 : {b})"
        q = f"({a} / {safe})"
        return f"({b} == 0 ? 0 : {q})" if div else f"({b} == 0 ? 0 : ({a} - {q} * {safe}))"

    def render_math(self, ins: ir.Instr) -> str:
        (a,) = self.operands(ins)
        return f"{ins.op.value}({a})"

    def render_abs(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        (a,) = self.operands(ins)
        if t.is_float:
            return f"abs({a})"
        return f"({a} < 0 ? (-{a}) : {a})" if t.is_signed else a

    def render_cast(self, ins: ir.Instr) -> str:
        src, dst = self.elem(ins), ins.type
        assert isinstance(dst, ir.ScalarType)
        (a,) = self.operands(ins)
        if src.name == dst.name:
            return a
        if dst.name == "bool":
            return f"({a} != {_ZERO[src.name]})"
        if src.is_float and dst.is_int:
            return self.saturate(a, dst)
        if src.name == "i32" and dst.name == "u64":
            return f"uint64_t(int64_t({a}))"  # sign-extends, as the IR's cast
        return f"{GLSL_TYPES[dst.name]}({a})"

    def saturate(self, a: str, dst: ir.ScalarType) -> str:
        """f32 -> int truncating toward zero, saturating, NaN -> 0 (GLSL leaves an
        out-of-range conversion undefined)."""
        b = dst.bits - 1 if dst.is_signed else dst.bits
        lo, hi = (-(2.0 ** b), 2.0 ** b) if dst.is_signed else (0.0, 2.0 ** b)
        top = glsl_int((1 << b) - 1, dst.name)
        lo_f, below_f, hi_f = (glsl_float(x) for x in (lo, hi * (1.0 - 2.0 ** -24), hi))
        c = GLSL_TYPES[dst.name]
        return (f"({a} >= {hi_f} ? {top} : {a} > {below_f} ? {c}({below_f}) : "
                f"{a} < {lo_f} ? {c}({lo_f}) : {a} != {a} ? {_ZERO[dst.name]} : {c}({a}))")

    def render_bitcast(self, ins: ir.Instr) -> str:
        src, dst = self.elem(ins), ins.type
        (a,) = self.operands(ins)
        if src.name == dst.name:
            return a
        if src.is_float:
            return f"floatBits{'ToInt' if dst.name == 'i32' else 'ToUint'}({a})"
        if dst.is_float:
            return f"{'int' if src.name == 'i32' else 'uint'}BitsToFloat({a})"
        return f"{GLSL_TYPES[dst.name]}({a})"

    # -- memory: SSBO arrays of GLSL_MEM, tables as constant arrays of their bits ---------
    def render_table(self, ins: ir.Instr) -> None:
        super().render_table(ins)
        self.table_names.add(self.names[ins.result])

    def ref(self, buf: ir.Value, idx: ir.Value) -> str:
        """The GLSL lvalue of element ``idx`` of a buffer: a buffer parameter is a range of
        its element type's pool, from the offset ``pooled`` names (see glsl_entry.py)."""
        name = self.v(buf)
        if name in self.pooled:
            pool, base = self.pooled[name]
            return f"{pool}.d[{base} + uint({self.v(idx)})]"
        return f"{name}[{self.v(idx)}]"

    def element(self, buf: ir.Value, idx: ir.Value) -> str:
        """The GLSL value of element ``idx`` of a buffer or table."""
        name, e = self.v(buf), buf.type.elem.name  # type: ignore[attr-defined]
        if name in self.table_names:
            return f"uintBitsToFloat({name}[{self.v(idx)}])"
        ref = self.ref(buf, idx)
        return f"({ref} != 0u)" if e == "bool" else ref

    def stored(self, buf: ir.Value, val: ir.Value) -> str:
        e = buf.type.elem.name  # type: ignore[attr-defined]
        return f"uint({self.v(val)})" if e == "bool" else self.v(val)

    def render_load(self, ins: ir.Instr) -> str:
        return self.element(*ins.operands)

    def render_gather(self, ins: ir.Instr) -> str:
        buf, idx, mask = ins.operands
        t = ins.type
        assert isinstance(t, ir.ScalarType)
        return f"({self.v(mask)} ? {self.element(buf, idx)} : {_ZERO[t.name]})"

    def render_store(self, ins: ir.Instr) -> None:
        buf, idx, val = ins.operands
        self.line(f"{self.ref(buf, idx)} = {self.stored(buf, val)};")

    def render_scatter(self, ins: ir.Instr) -> None:
        buf, idx, val, mask = ins.operands
        self.line(f"if ({self.v(mask)}) {self.ref(buf, idx)} = {self.stored(buf, val)};")


def check_width(module: ir.Module) -> int:
    """The module's width (1), or a diagnostic."""
    return GlslBackend().check_module(module)


__all__ = ["FMODF", "GLSL_MEM", "GLSL_TYPES", "GlslBackend", "GlslPrinter", "check_width",
           "glsl_float", "glsl_int"]
