"""The ``lift`` pass itself: the walk over a module that lifts types, folds the ``if const``
traits, and hands each instruction to the lowering of the variant's spectrum (unpolarized,
Mueller or spectral; see the package's docstring for the contract)."""

from __future__ import annotations

from ....core.color import RGB, ColorModel
from ...diagnostics import CompileError, Diagnostic
from ...ir import (
    Block,
    Builder,
    Instr,
    Module,
    Op,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    UnpolarizedType,
    Value,
    replace_uses,
)
from .. import Pass, register
from .model import concrete_type, unpolarized_type
from .mueller import Mueller
from .spectral import Spectral
from .unpolarized import rewrite_unpolarized


@register
class Lift(Pass):
    """Give ``Spectrum`` the concrete representation of a colour model."""

    name = "lift"

    def __init__(self, model: ColorModel = RGB, differentiated: bool = False) -> None:
        self.model = model
        # `if const differentiated`: true in a build with derivatives
        self.build_traits = frozenset({"differentiated"} if differentiated else ())
        # per function, set by run
        self.traits: set[Value] = set()
        self.fn_traits: frozenset[str] = self.model.traits | self.build_traits
        self.spectral: Spectral | None = None
        self.mueller: Mueller | None = None

    # -- types -------------------------------------------------------------------------
    def lift_type(self, t: Type) -> Type:
        if isinstance(t, UnpolarizedType):
            return unpolarized_type(self.model, t.lanes)
        if isinstance(t, SpectrumType):
            return concrete_type(self.model, t.lanes)
        if isinstance(t, StructType):
            fields = tuple((n, self.lift_type(ft)) for n, ft in t.fields)
            return StructType(t.name, fields, lanes=t.lanes)
        if isinstance(t, TupleType):
            return TupleType(tuple(self.lift_type(e) for e in t.elems), lanes=t.lanes)
        return t

    # -- module ------------------------------------------------------------------------
    def run(self, module: Module) -> None:
        module.attrs["variant"] = self.model.name
        module.structs = {k: self.lift_type(v) for k, v in module.structs.items()}
        if self.model.polarized:
            module.structs["Mueller"] = concrete_type(self.model)
        for fn in module.functions.values():
            for p in fn.params:
                p.value.type = self.lift_type(p.value.type)
            fn.ret_types = [self.lift_type(t) for t in fn.ret_types]
            mapping: dict[Value, Value] = {}
            self.traits = set()
            # `if const wavelengths`: this kernel has wavelengths (a plugin compiled on its own
            # has none, so code that needs them can fall back)
            sets = self.model.n == 4 and any(i.op is Op.SPEC_SET for i in fn.walk())
            self.fn_traits = self.model.traits | self.build_traits | (
                {"wavelengths"} if sets else set())
            self._fold_traits(fn.body, mapping)
            replace_uses(fn.body, mapping)
            self.spectral = Spectral(self.model, fn.loc) if self.model.n == 4 else None
            self.mueller = Mueller(self.model) if self.model.polarized else None
            mapping = {}
            self.lift_block(fn.body, mapping, top=True)
            replace_uses(fn.body, mapping)
            if self.spectral is not None:
                at = self.spectral.set_at
                fn.body.instrs[at:at] = self.spectral.prelude.block.instrs
                fn.body.instrs[:0] = self.spectral.tables.block.instrs

    def _fold_traits(self, block: Block, mapping: dict[Value, Value]) -> None:
        """Trait constants become booleans and the branches they rule out disappear (their
        results map, possibly through a chain, to the values the taken branch yields)."""
        def find(v: Value) -> Value:
            while v in mapping:
                v = mapping[v]
            return v

        out: list[Instr] = []
        work = list(block.instrs)
        while work:
            ins = work.pop(0)
            ins.operands = [find(v) for v in ins.operands]
            if ins.op is Op.CONST and "trait" in ins.attrs:
                ins.attrs = {"value": ins.attrs["trait"] in self.fn_traits}
                self.traits.add(ins.result)
            if ins.op is Op.IF and ins.operands[0] in self.traits:
                cond = ins.operands[0].owner.attrs["value"]
                taken = ins.regions[0 if cond else 1]
                work[:0] = taken.instrs[:-1]
                for r, v in zip(ins.results, taken.instrs[-1].operands):
                    mapping[r] = v
                continue
            for r in ins.regions:
                self._fold_traits(r, mapping)
            out.append(ins)
        block.instrs = out
        for k in list(mapping):
            mapping[k] = find(k)

    def lift_block(self, block: Block, mapping: dict[Value, Value], top: bool = False) -> None:
        """Lift ``block`` in place; ``mapping`` collects the replaced results."""
        for a in block.args:
            a.type = self.lift_type(a.type)
        out: list[Instr] = []
        for ins in block.instrs:
            if self.mueller is not None and ins.op is Op.LOOP:
                out.extend(self.mueller.loop(self, ins, mapping))
                continue
            for r in ins.regions:
                self.lift_block(r, mapping)
            for r in ins.results:
                r.type = self.lift_type(r.type)
            b = Builder(Block(), ins.loc)
            ops = [mapping.get(v, v) for v in ins.operands]
            if ins.op is Op.SPEC_SET:
                wl = ops[0]
                if self.mueller is not None and self.mueller.is_mueller(wl):
                    wl = self.mueller.entry(b, wl, 0, 0)
                    out.extend(b.block.instrs)
                self._set_wavelengths(ins, wl, top)
                if self.spectral is not None:
                    self.spectral.set_at = len(out)  # where what depends on them alone goes
                continue
            if self.mueller is not None:
                replaced = self.mueller.rewrite(self, ins, b, ops)
            else:
                replaced = rewrite_unpolarized(self, ins, b, ops)
            if replaced is None:
                out.append(ins)
                if self.mueller is not None:
                    if ins.op is Op.IF:
                        out.extend(self.mueller.merge(ins, mapping))
                    else:
                        self.mueller.track(ins, b, ops)
                        out.extend(b.block.instrs)
            else:
                out.extend(b.block.instrs)
                mapping[ins.result] = replaced
        block.instrs = out

    def _set_wavelengths(self, ins: Instr, wl: Value, top: bool) -> None:
        if self.spectral is None:
            return  # only spectral variants have wavelengths; the call is dropped
        if not top:
            raise CompileError([Diagnostic(ins.loc, "`set_wavelengths` must be called in the "
                                           "kernel's top-level block, not inside a branch "
                                           "or loop")])
        if self.spectral.wavelengths is not None:
            raise CompileError([Diagnostic(ins.loc, "the wavelengths are already set")])
        self.spectral.wavelengths = wl

