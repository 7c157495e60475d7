"""The SIMD C backend: post-vectorize IR -> one standalone ``.c`` file (plus the ``.h`` of
``clib.header``) that needs libc and libm only.

Varying values are GCC/Clang vector extensions of the module's width W
(``float __attribute__((vector_size(4 * W)))``), so ``cc -O2 -march=native`` compiles them
to SSE, AVX2 or AVX-512 registers; at W = 1 the code is plain scalar C.  A varying ``bool``
is a vector of ``int32_t`` lanes that are 0 or -1 (what vector comparisons give), selects are
bitwise, ``sqrt``/``floor``/``ceil`` use the x86 intrinsics when the compiler targets them
and a lane loop over libm's ``sqrtf``/``floorf``/``ceilf`` otherwise (all exactly rounded,
so the C build agrees with the interpreter bit for bit: the IR has no other transcendental,
``exp``/``sin``/... are written in rdsl and arrive here as IR).  ``rem`` on f32 is libm's
``fmodf`` (exact).  Floating-point contraction is off (a pragma, and ``-ffp-contract=off``).

The entry points have the C ABI of the LLVM backend (``base.c_prototype``): a byte stride
after every array, a mask of bytes, outputs written for active lanes only, uniform results
broadcast.  The source compiles warning-free with ``cc -std=c11 -Wall -Wextra`` (vector
extensions and ``__builtin_convertvector`` are accepted in ISO mode; ``-pedantic`` would
object to them).
"""

from __future__ import annotations

from typing import ClassVar

from .. import ir
from ..diagnostics import CompileError
from .base import Backend, c_name, kernels
from .c_like import SCALAR_C, CLikePrinter, saturation

VEC_NAMES = {"f32": "rdsl_f32v", "i32": "rdsl_i32v", "u32": "rdsl_u32v",
             "u64": "rdsl_u64v", "bool": "rdsl_maskv"}
_MATH_MACRO = {ir.Op.SQRT: "RDSL_SQRT", ir.Op.FLOOR: "RDSL_FLOOR", ir.Op.CEIL: "RDSL_CEIL"}


class CBackend(Backend):
    """Portable SIMD C (GCC/Clang vector extensions), compiled by the machine's ``cc``."""

    name = "c"
    emits = ("c", "h", "so")
    supports_gather = True
    supports_scatter = True
    supports_float_rem = True
    max_width = 16
    widths = (1, 4, 8, 16)


class SimdC(CLikePrinter):
    """The C-like printer with varying values as vector-extension types of ``width``."""

    target_name: ClassVar[str] = "c"
    float_minmax: ClassVar[bool] = True  # f32 min/max through the prelude's RDSL_MINF/MAXF

    def __init__(self, width: int, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.W = width

    def vtype(self, dtype: str) -> str:
        return VEC_NAMES[dtype]

    def splat(self, t: ir.ScalarType, scalar: str) -> str:
        return scalar if t.lanes == 1 else f"RDSL_SPLAT({self.ctype(t)}, {scalar})"

    # -- masks and selects ----------------------------------------------------------------
    def bits_type(self, t: ir.ScalarType) -> str:
        """The signed vector type of ``t``'s lane width (what a comparison of ``t`` gives)."""
        return "rdsl_i64v" if t.name == "u64" else "rdsl_i32v"

    def select_raw(self, t: ir.ScalarType, m: str, a: str, b: str) -> str:
        """Bitwise select with ``m`` a mask of ``t``'s lane width (0 or -1 per lane)."""
        s = self.bits_type(t)
        sa, sb = self.reinterpret(s, a), self.reinterpret(s, b)
        return self.reinterpret(self.ctype(t), f"(({sa} & {m}) | ({sb} & ~{m}))")

    def widen_mask(self, t: ir.ScalarType, m: str) -> str:
        """A varying bool (32-bit lanes) as a mask of ``t``'s lane width."""
        return self.convert(m, "rdsl_i64v") if t.name == "u64" else m

    def convert(self, expr: str, vtype: str) -> str:
        """Vector ``expr`` converted lane by lane (value-preserving, C rules) to ``vtype``."""
        return f"__builtin_convertvector({expr}, {vtype})"

    def lane_ref(self, var: str, t: ir.ScalarType, k: str = "k") -> str:
        """Lane ``k`` of vector variable ``var`` (of type ``t``), as an lvalue."""
        return f"{var}[{k}]"

    def vec_literal(self, vtype: str, items: list[str]) -> str:
        return f"(({vtype}){{" + ", ".join(items) + "})"

    def select(self, t: ir.ScalarType, cond: ir.Value, a: str, b: str) -> str:
        if cond.type.lanes == 1 or t.lanes == 1:
            return super().select(t, cond, a, b)
        return self.select_raw(t, self.widen_mask(t, self.v(cond)), a, b)

    def select_cmp(self, t: ir.ScalarType, cond: str, a: str, b: str) -> str:
        return super().select_cmp(t, cond, a, b) if t.lanes == 1 else \
            self.select_raw(t, cond, a, b)

    def render_minmax(self, ins: ir.Instr) -> str:
        t = ins.type
        if t.lanes == 1 or t.name != "f32" or not self.float_minmax:
            return super().render_minmax(ins)
        a, b = self.operands(ins)  # x86's minps/maxps are select(a < b, a, b), exactly
        return f"RDSL_{'MIN' if ins.op is ir.Op.MIN else 'MAX'}F({a}, {b})"

    def render_cmp(self, ins: ir.Instr) -> str:
        r = super().render_cmp(ins)
        t = self.elem(ins)
        if t.lanes > 1 and t.name == "u64":  # 64-bit lanes -> the 32-bit mask
            return self.convert(r, "rdsl_i32v")
        return r

    def temp(self, t: ir.ScalarType | str, expr: str) -> str:
        """A C variable holding ``expr`` (``t``: an IR type or a C type name)."""
        name = self.fresh()
        self.line(f"{t if isinstance(t, str) else self.ctype(t)} {name} = {expr};")
        return name

    # -- arithmetic -----------------------------------------------------------------------
    def render_divrem(self, ins: ir.Instr) -> str | None:
        t = self.elem(ins)
        if t.lanes == 1:
            return super().render_divrem(ins)
        a, b = self.operands(ins)
        div = ins.op is ir.Op.DIV
        if t.is_float:
            if div:
                return f"({a} / {b})"
            r = self.declare(ins.result, None)
            self.line(f"for (int k = 0; k < {self.W}; ++k) {self.lane_ref(r, t)} = "
                      f"fmodf({self.lane_ref(a, t)}, {self.lane_ref(b, t)});")
            return None
        zero = self.temp(self.bits_type(t), f"({b} == 0)")
        bad = zero
        if t.is_signed:  # INT_MIN / -1 overflows: divide by 1 (INT_MIN / 1, INT_MIN % 1 = 0)
            bad = f"({zero} | (({a} == (-2147483647 - 1)) & ({b} == -1)))"
        safe = self.temp(t, self.select_raw(t, bad, self.splat(t, "1"), b))
        q = f"({a} / {safe})" if div else f"({a} % {safe})"
        return self.select_raw(t, zero, self.splat(t, "0"), q)

    def render_math(self, ins: ir.Instr) -> str | None:
        if ins.type.lanes == 1:
            return super().render_math(ins)
        (a,) = self.operands(ins)
        r = self.declare(ins.result, None)
        self.line(f"{_MATH_MACRO[ins.op]}({r}, {a});")
        return None

    def render_abs(self, ins: ir.Instr) -> str:
        t = self.elem(ins)
        if t.lanes == 1:
            return super().render_abs(ins)
        (a,) = self.operands(ins)
        if t.is_float:
            return self.reinterpret("rdsl_f32v",
                                    f"({self.reinterpret('rdsl_u32v', a)} & 0x7fffffffu)")
        if t.is_signed:
            s = self.reinterpret("rdsl_u32v", f"({a} >> 31)")
            ua = self.reinterpret("rdsl_u32v", a)
            return self.reinterpret("rdsl_i32v", f"(({ua} ^ {s}) - {s})")
        return a

    # -- conversions ----------------------------------------------------------------------
    def render_cast(self, ins: ir.Instr) -> str | None:
        src, dst = self.elem(ins), ins.type
        assert isinstance(dst, ir.ScalarType)
        if dst.lanes == 1:
            return super().render_cast(ins)
        (a,) = self.operands(ins)
        T = self.ctype(dst)
        if src.name == dst.name:
            return a
        if {src.name, dst.name} == {"i32", "u32"}:
            return self.reinterpret(T, a)
        if dst.name == "bool":
            zero = "0.0f" if src.is_float else "0"
            r = f"({a} != {zero})"
            return self.convert(r, "rdsl_i32v") if src.name == "u64" else r
        if src.name == "bool":
            return self.convert(f"({a} & 1)", T)
        if src.is_float:
            return self.vector_saturate(a, dst)
        if src.name == "i32" and dst.name == "u64":
            return self.reinterpret("rdsl_u64v", self.convert(a, "rdsl_i64v"))
        if src.name == "u64" and dst.name == "i32":
            return self.reinterpret("rdsl_i32v", self.convert(a, "rdsl_u32v"))
        return self.convert(a, T)

    def vector_saturate(self, a: str, dst: ir.ScalarType) -> str:
        """f32 -> int truncating toward zero, saturating, NaN -> 0 (as LLVM's fpto*i.sat)."""
        lo, below_hi, hi, top = saturation(dst)
        f = ir.ScalarType("f32", lanes=dst.lanes)
        x = self.temp(f, self.select_raw(f, f"({a} > {below_hi})", self.splat(f, below_hi), a))
        x = self.temp(f, self.select_raw(f, f"({x} < {lo})", self.splat(f, lo), x))
        x = self.temp(f, self.select_raw(f, f"({x} != {x})", self.splat(f, "0.0f"), x))
        r = self.temp(dst, self.convert(x, self.ctype(dst)))
        over = self.widen_mask(dst, f"({a} >= {hi})")
        return self.select_raw(dst, over, self.splat(dst, top), r)

    def render_bitcast(self, ins: ir.Instr) -> str:
        if ins.type.lanes == 1:
            return super().render_bitcast(ins)
        (a,) = self.operands(ins)
        return self.reinterpret(self.ctype(ins.type), a)

    # -- lanes and memory ----------------------------------------------------------------
    def render_any(self, ins: ir.Instr) -> str | None:
        if self.elem(ins).lanes == 1:
            return super().render_any(ins)
        (a,) = self.operands(ins)
        r = self.declare(ins.result, None)
        self.line(f"RDSL_ANY({r}, {a});")
        return None

    def render_lane(self, ins: ir.Instr) -> str:
        if ins.type.lanes == 1:
            return "0"
        return self.vec_literal("rdsl_i32v", [str(k) for k in range(ins.type.lanes)])

    def lane(self, value: ir.Value, k: str = "k") -> str:
        """Lane ``k`` of a value (a uniform value is the same in every lane)."""
        t = value.type
        assert isinstance(t, ir.ScalarType)
        return self.v(value) if t.lanes == 1 else self.lane_ref(self.v(value), t, k)

    def render_gather(self, ins: ir.Instr) -> str | None:
        if ins.type.lanes == 1:
            return super().render_gather(ins)
        buf, idx, mask = ins.operands
        e = buf.type.elem.name  # type: ignore[attr-defined]
        r = self.declare(ins.result, None)
        macro = self.gather_macro(e, idx, mask)
        if macro:  # the hardware gather (c_entry.prelude), or its lane loop
            self.line(f"{macro}({self.ctype(ins.type)}, {r}, {self.v(buf)}, {self.v(idx)}, "
                      f"{self.v(mask)});")
            return None
        loaded = self.mem_to_value(e, f"{self.v(buf)}[{self.lane(idx)}]", 2)
        self.line(f"for (int k = 0; k < {self.W}; ++k) "
                  f"if ({self.lane(mask)}) {self.lane_ref(r, ins.type)} = {loaded};")
        return None

    def gather_macro(self, e: str, idx: ir.Value, mask: ir.Value) -> str | None:
        """The prelude's macro for a gather of 4-byte elements (buffer type ``e``) at
        varying i32 indices under a varying mask (``RDSL_GATHER32``: one instruction where
        the compiler targets AVX2 or AVX-512, else a lane loop), or None (the loop here)."""
        return "RDSL_GATHER32" if _lanes_of_32_bits(e, idx, mask) else None

    def render_scatter(self, ins: ir.Instr) -> None:
        buf, idx, val, mask = ins.operands
        if mask.type.lanes == 1:
            return super().render_scatter(ins)
        e = buf.type.elem.name  # type: ignore[attr-defined]
        if self.gather_macro(e, idx, mask) and val.type.lanes > 1:  # type: ignore[attr-defined]
            # the scatter of the same lanes (AVX-512: lanes in order, the last one wins)
            self.line(f"RDSL_SCATTER32({self.v(buf)}, {self.v(idx)}, {self.v(val)}, "
                      f"{self.v(mask)});")
            return None
        v = self.lane(val)
        if e == "bool":
            v = f"(uint8_t)({v} != 0)"
        self.line(f"for (int k = 0; k < {self.W}; ++k) "
                  f"if ({self.lane(mask)}) {self.v(buf)}[{self.lane(idx)}] = {v};")
        return None


def _lanes_of_32_bits(e: str, idx: ir.Value, mask: ir.Value) -> bool:
    """Whether a gather or scatter reaches 4-byte elements at varying i32 indices under a
    varying mask (what one x86 gather or scatter instruction does)."""
    t, m = idx.type, mask.type
    assert isinstance(t, ir.ScalarType) and isinstance(m, ir.ScalarType)
    return e in ("f32", "i32", "u32") and t.name == "i32" and t.lanes > 1 and m.lanes > 1


# --------------------------------------------------------------------------------------
# Public API


def check_width(module: ir.Module) -> int:
    """The module's width, or a diagnostic if the C backend does not support it."""
    return CBackend().check_module(module)


def emit_c(module: ir.Module, stem: str) -> str:
    """The C source of every kernel of ``module`` (it includes ``<stem>.h``)."""
    from .c_entry import module_source

    width = check_width(module)
    seen: dict[str, str] = {}
    for fn in kernels(module):
        other = seen.setdefault(c_name(fn.name), fn.name)
        if other != fn.name:
            raise CompileError(f"kernels `{other}` and `{fn.name}` both export the C "
                               f"symbol rdsl_{c_name(fn.name)}", fn.loc)
    return module_source(module, width, stem)


__all__ = ["SCALAR_C", "CBackend", "SimdC", "check_width", "emit_c"]
