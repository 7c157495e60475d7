"""``lift(variant)``: give the abstract ``Spectrum`` a concrete representation.

Expects: an inlined module (no calls) whose values may have type ``spectrum`` or aggregates
containing it, ``spec.*`` ops, and ``const trait "<name>"`` booleans from ``if const``.

Guarantees: no value has a ``spectrum`` type; no ``spec.*`` op and no trait constant
remains.  What each variant's spectrum becomes is described by a :class:`SpectrumModel`, so
the spectral and polarized models plug in beside mono and rgb without touching the rest of
the pass.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..diagnostics import CompileError, Diagnostic
from ..ir import (
    F32,
    Block,
    Builder,
    Instr,
    MatType,
    Module,
    Op,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    Value,
    VecType,
    replace_uses,
)
from . import Pass, register

VARIANTS = ("mono", "rgb", "spectral", "mono_polarized", "spectral_polarized")

# CIE Y weights of linear sRGB primaries: what a mono variant sees of an RGB value.
_LUMINANCE = (0.212671, 0.715160, 0.072169)


@dataclass(frozen=True)
class SpectrumModel:
    """How a variant represents ``Spectrum``: ``n`` f32 samples (1 = a plain ``f32``)."""

    variant: str
    n: int
    traits: frozenset[str]

    def concrete(self, lanes: int = 1) -> Type:
        return F32.with_lanes(lanes) if self.n == 1 else VecType(self.n, lanes=lanes)


MODELS = {
    "mono": SpectrumModel("mono", 1, frozenset({"mono"})),
    "rgb": SpectrumModel("rgb", 3, frozenset({"rgb"})),
}


def model_for(variant: str) -> SpectrumModel:
    """The spectrum model of ``variant``, or a diagnostic naming the accepted variants."""
    if variant in MODELS:
        return MODELS[variant]
    if variant in VARIANTS:
        raise CompileError(f"variant `{variant}` is not implemented yet "
                           f"(available: {', '.join(MODELS)})")
    raise CompileError(f"unknown variant `{variant}` (expected one of: {', '.join(VARIANTS)})")


@register
class Lift(Pass):
    name = "lift"

    def __init__(self, variant: str = "rgb") -> None:
        self.model = model_for(variant)

    # -- types -------------------------------------------------------------------------
    def lift_type(self, t: Type) -> Type:
        if isinstance(t, SpectrumType):
            return self.model.concrete(t.lanes)
        if isinstance(t, StructType):
            fields = tuple((n, self.lift_type(ft)) for n, ft in t.fields)
            return StructType(t.name, fields, lanes=t.lanes)
        if isinstance(t, TupleType):
            return TupleType(tuple(self.lift_type(e) for e in t.elems), lanes=t.lanes)
        return t

    # -- module ------------------------------------------------------------------------
    def run(self, module: Module) -> None:
        module.attrs["variant"] = self.model.variant
        module.structs = {k: self.lift_type(v) for k, v in module.structs.items()}
        for fn in module.functions.values():
            for p in fn.params:
                p.value.type = self.lift_type(p.value.type)
            fn.ret_types = [self.lift_type(t) for t in fn.ret_types]
            mapping: dict[Value, Value] = {}
            self._block(fn.body, mapping)
            replace_uses(fn.body, mapping)

    def _block(self, block: Block, mapping: dict[Value, Value]) -> None:
        for a in block.args:
            a.type = self.lift_type(a.type)
        out: list[Instr] = []
        for ins in block.instrs:
            for r in ins.regions:
                self._block(r, mapping)
            for r in ins.results:
                r.type = self.lift_type(r.type)
            b = Builder(Block(), ins.loc)
            replaced = self._rewrite(ins, b, [mapping.get(v, v) for v in ins.operands])
            if replaced is None:
                out.append(ins)
            else:
                out.extend(b.block.instrs)
                mapping[ins.result] = replaced
        block.instrs = out

    def _rewrite(self, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
        """Return the replacement of ``ins``'s result, or None to keep ``ins``."""
        n = self.model.n
        if ins.op is Op.CONST and "trait" in ins.attrs:
            return b.const(ins.attrs["trait"] in self.model.traits, ins.type)
        if ins.op is Op.BROADCAST and n == 1 and isinstance(ops[0].type, ScalarType) \
                and ins.type == ops[0].type:
            return ops[0]
        if ins.op is Op.SPEC_AVG:
            return self._reduce(b, ops[0], Op.ADD, divide=True)
        if ins.op is Op.SPEC_MAX:
            return self._reduce(b, ops[0], Op.MAX)
        if ins.op is Op.SPEC_RGB:
            if n == 3:
                return b.op(Op.MAKE, ins.type, *ops)
            if n == 1:
                acc = None
                for w, v in zip(_LUMINANCE, ops):
                    term = b.op(Op.MUL, F32, b.const(w, F32), v)
                    acc = term if acc is None else b.op(Op.ADD, F32, acc, term)
                return acc
            raise CompileError([Diagnostic(ins.loc, "Spectrum(r, g, b) needs RGB upsampling, "
                                           f"not available in `{self.model.variant}`")])
        if ins.op in (Op.MUL, Op.DIV) and isinstance(ins.type, MatType):
            raise CompileError([Diagnostic(ins.loc, "matrix spectra are not supported here")])
        return None

    def _reduce(self, b: Builder, v: Value, op: Op, divide: bool = False) -> Value:
        if self.model.n == 1:
            return v
        parts = [b.op(Op.EXTRACT, F32, v, index=i) for i in range(self.model.n)]
        acc = parts[0]
        for p in parts[1:]:
            acc = b.op(op, F32, acc, p)
        if divide:
            acc = b.op(Op.DIV, F32, acc, b.const(float(self.model.n), F32))
        return acc
