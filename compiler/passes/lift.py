"""``lift(model)``: give the abstract ``Spectrum`` a concrete representation.

Expects: an inlined module (no calls) whose values may have type ``spectrum`` or aggregates
containing it, ``spec.*`` ops, and ``const trait "<name>"`` booleans from ``if const``.

Guarantees: no value has a ``spectrum`` type; no ``spec.*`` op and no trait constant
remains, and the branches of ``if const`` that the variant does not take are gone (so code
valid in one variant only may sit inside them).  What each variant's spectrum becomes is
described by its :class:`~rdsl.core.color.ColorModel`.

Spectral variants (``n = 4``) carry the four wavelengths of a sample as an implicit value:
``set_wavelengths(wl)`` in the kernel's top-level block defines it, and every colour after it
is evaluated there.  The trait ``wavelengths`` (``if const wavelengths``) is true in a kernel
that sets them, so that code needing them can fall back in one that does not (a plugin
compiled on its own).  Colours become spectra as in Mitsuba 3:

* ``Spectrum(r, g, b)`` with constant arguments is a reflectance: the Jakob & Hanika 2019
  sigmoid polynomial whose sRGB colour is (r, g, b), its coefficients found at compile time.
  With a tabulated spectrum attached (``spectrum`` attribute: the wavelengths and values of a
  scene's ``<spectrum>``, spectrum file or named conductor), that spectrum is evaluated
  instead, exactly (to float32 rounding) as Mitsuba's ``irregular``: the linear interpolant
  of its knots, 0 outside them (and outside 360..830 nm).  A table of regular cells over its
  range, no wider than its knots' spacing, holds per cell its knot and the lines either side
  (``core/spectral.py``: ``tabulated_cells``); a wavelength's cell gives the knot, the
  knot the line: three loads, no search.
* ``spec.table(buf, offset)``, a tabulated spectrum the generic build stores in ``PRM``, is
  evaluated the same way from the fixed 1 nm cells over 360..830 nm stored there
  (``tabulated_slot``; see ``parameter_slots`` in specialize.py for when they are exact); a
  select between two such spectra reads the table at the selected offset.
* ``illuminant(r, g, b)`` is an emitted colour: the upsampled colour, scaled, times the D65
  illuminant (Mitsuba's ``d65`` plugin), so that white light stays white.
* With arguments read from buffers, the runtime has stored coefficients there (and, for
  ``illuminant(c0, c1, c2, scale)``, the scale): they are evaluated as they are.  Other
  computed arguments are a diagnostic: there is no run-time RGB fit.
* ``to_srgb(s)`` integrates the four samples against the CIE 1931 curves (the weights of
  the wavelength sampling must already be in ``s``) and converts XYZ to linear sRGB.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...core.color import RGB, ColorModel
from ..diagnostics import CompileError, Diagnostic
from ..ir import (
    ARITH_OPS,
    BOOL,
    F32,
    I32,
    Block,
    BufferType,
    Builder,
    Instr,
    Module,
    Op,
    ScalarType,
    SpectrumType,
    StructType,
    TupleType,
    Type,
    UnpolarizedType,
    Value,
    VecType,
    clone_block,
    components,
    replace_uses,
)
from . import Pass, register

# CIE Y weights of linear sRGB primaries: what a mono variant sees of an RGB value.
_LUMINANCE = (0.212671, 0.715160, 0.072169)


def unpolarized_type(model: ColorModel, lanes: int = 1) -> Type:
    """The lifted ``Unpolarized``: ``f32`` for one sample, else a vector of ``model.n``."""
    return F32.with_lanes(lanes) if model.n == 1 else VecType(model.n, lanes=lanes)


def concrete_type(model: ColorModel, lanes: int = 1) -> Type:
    """The lifted ``Spectrum``: the unpolarized type, or a Mueller matrix of it (the struct
    ``%Mueller``, row-major fields ``m00 .. m33``)."""
    if model.polarized:
        return mueller_type(unpolarized_type(model), lanes)
    return unpolarized_type(model, lanes)


MUELLER_FIELDS = tuple(f"m{i}{j}" for i in range(4) for j in range(4))


def mueller_type(entry: Type, lanes: int = 1) -> StructType:
    """The lifted polarized ``Spectrum``: 16 entries, row-major."""
    return StructType("Mueller", tuple((f, entry) for f in MUELLER_FIELDS), lanes=lanes)


@register
class Lift(Pass):
    name = "lift"

    def __init__(self, model: ColorModel = RGB) -> None:
        self.model = model

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
            self.traits: set[Value] = set()
            # `if const wavelengths`: this kernel has wavelengths (a plugin compiled on its own
            # has none, so code that needs them can fall back)
            sets = self.model.n == 4 and any(i.op is Op.SPEC_SET for i in fn.walk())
            self.fn_traits = self.model.traits | ({"wavelengths"} if sets else set())
            self._fold_traits(fn.body, mapping)
            replace_uses(fn.body, mapping)
            self.spectral = _Spectral(self.model, fn.loc) if self.model.n == 4 else None
            self.mueller = _Mueller(self.model) if self.model.polarized else None
            mapping = {}
            self._block(fn.body, mapping, top=True)
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

    def _block(self, block: Block, mapping: dict[Value, Value], top: bool = False) -> None:
        for a in block.args:
            a.type = self.lift_type(a.type)
        out: list[Instr] = []
        for ins in block.instrs:
            if self.mueller is not None and ins.op is Op.LOOP:
                out.extend(self.mueller.loop(self, ins, mapping))
                continue
            for r in ins.regions:
                self._block(r, mapping)
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
                replaced = self._rewrite(ins, b, ops)
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

    def _fail(self, ins: Instr, msg: str) -> CompileError:
        return CompileError([Diagnostic(ins.loc, msg)])

    def _rewrite(self, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
        """Return the replacement of ``ins``'s result, or None to keep ``ins``.  Unpolarized
        values only: ``ins.type`` is the concrete spectrum (or what a spectrum op gives)."""
        n = self.model.n
        variant = self.model.name
        if ins.op is Op.BROADCAST and n == 1 and isinstance(ops[0].type, ScalarType) \
                and ins.type == ops[0].type:
            return ops[0]
        if ins.op is Op.SPEC_AVG:
            return self._reduce(b, ops[0], Op.ADD, divide=True)
        if ins.op is Op.SPEC_MAX:
            return self._reduce(b, ops[0], Op.MAX)
        if ins.op is Op.SPEC_MAKE:
            if len(ops) != n:
                raise self._fail(ins, f"a Spectrum of {len(ops)} components does not exist in "
                                 f"the `{variant}` variant ({n} component"
                                 f"{'s' if n > 1 else ''}); use it inside `if const`")
            return b.op(Op.MAKE, ins.type, *ops) if n > 1 else ops[0]
        if ins.op is Op.SPEC_LAMBDA:
            if self.spectral is None:
                raise self._fail(ins, f"`wavelengths()` has no meaning in the `{variant}` "
                                 "variant; use it inside `if const spectral`")
            return self.spectral.lam(ins)
        if ins.op is Op.SPEC_SRGB:
            if n == 3:
                return ops[0]
            if n == 1:
                return b.op(Op.MAKE, ins.type, ops[0], ops[0], ops[0])
            return self.spectral.to_srgb(b, ins, ops[0])
        if ins.op is Op.SPEC_RGB:
            illum = bool(ins.attrs.get("illuminant"))
            if n == 4:
                return self.spectral.from_rgb(b, ins, ops, illum)
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
        if ins.op is Op.SPEC_TABLE:
            if self.spectral is None:
                raise self._fail(ins, f"a tabulated spectrum read from a buffer exists in "
                                 f"spectral variants only (this is `{variant}`)")
            return self.spectral.stored_table(b, ins, ops[0], ops[1])
        if ins.op is Op.SELECT and self.spectral is not None:
            return self.spectral.select(b, ins, ops)
        # Unpolarized variants: a spectrum is its own unpolarized part, and is read as
        # depolarized light (only the intensity entry [0][0] exists).
        if ins.op in (Op.SPEC_UNPOL, Op.SPEC_FROM, Op.SPEC_DEPOL):
            return ops[0]
        if ins.op is Op.SPEC_ENTRY:
            if (ins.attrs["row"], ins.attrs["col"]) == (0, 0):
                return ops[0]
            zero = b.const(0.0, F32)
            return zero if n == 1 else b.op(Op.BROADCAST, ins.type, zero)
        if ins.op is Op.SPEC_MUELLER:
            raise self._fail(ins, f"`mueller(...)` builds a Mueller matrix, which exists in "
                             f"polarized variants only (this is `{variant}`); use it inside "
                             "`if const polarized`")
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


_ELEMENTWISE_ONLY = {Op.DIV: "divide", Op.REM: "take the remainder of", Op.SQRT: "`sqrt`",
                     Op.FLOOR: "`floor`", Op.CEIL: "`ceil`", Op.ABS: "`abs`", Op.MIN: "`min`",
                     Op.MAX: "`max`"}


class _Mueller:
    """The polarized lowering of one kernel: every ``Spectrum`` is a Mueller matrix of
    unpolarized values (Mitsuba 2, sec. 5: Stokes vectors are its first column).

    Within the kernel it remembers, for each matrix it built, its 16 entries (None where the
    entry is a known zero) and, for u * identity, the unpolarized u.  Products skip known
    zeros, and operations that only make sense elementwise (division, sqrt, min...) are
    allowed on matrices known to be u * identity, where they act on u."""

    def __init__(self, model: ColorModel) -> None:
        self.model = model
        self.base = unpolarized_type(model)
        self.type = concrete_type(model)
        self.entries: dict[Value, list[Value | None]] = {}
        self.scalar: dict[Value, Value] = {}
        self.parts: dict[Value, Any] = {}  # shapes of structs and tuples holding matrices

    def is_mueller(self, v: Value) -> bool:
        return isinstance(v.type, StructType) and v.type.name == "Mueller"

    # -- building blocks -----------------------------------------------------------------
    def zero(self, b: Builder) -> Value:
        z = b.const(0.0, F32)
        return z if self.model.n == 1 else b.op(Op.BROADCAST, self.base, z)

    def get(self, b: Builder, v: Value) -> list[Value | None]:
        if v in self.entries:
            return self.entries[v]
        return [b.op(Op.EXTRACT, self.base, v, index=i) for i in range(16)]

    def entry(self, b: Builder, v: Value, i: int, j: int) -> Value:
        if v in self.scalar:
            return self.scalar[v] if i == j else self.zero(b)
        e = self.get(b, v)[4 * i + j]
        return self.zero(b) if e is None else e

    def make(self, b: Builder, entries: list[Value | None]) -> Value:
        z = self.zero(b) if any(e is None for e in entries) else None
        v = b.op(Op.MAKE, self.type, *[z if e is None else e for e in entries])
        self.entries[v] = entries
        return v

    def from_scalar(self, b: Builder, u: Value) -> Value:
        v = self.make(b, [u if i % 5 == 0 else None for i in range(16)])
        self.scalar[v] = u
        return v

    def splat(self, b: Builder, x: Value) -> Value:
        """An f32 as an unpolarized value."""
        return x if self.model.n == 1 else b.op(Op.BROADCAST, self.base, x)

    def is_zero(self, v: Value) -> bool:
        ins = v.owner
        if isinstance(ins, Instr) and ins.op is Op.BROADCAST:
            ins = ins.operands[0].owner
        return isinstance(ins, Instr) and ins.op is Op.CONST and ins.attrs.get("value") == 0.0 \
            and "trait" not in ins.attrs

    def product(self, b: Builder, x: list[Value | None], y: list[Value | None]) -> list:
        out: list[Value | None] = []
        for i in range(4):
            for j in range(4):
                acc = None
                for k in range(4):
                    p, q = x[4 * i + k], y[4 * k + j]
                    if p is None or q is None:
                        continue
                    t = b.op(Op.MUL, self.base, p, q)
                    acc = t if acc is None else b.op(Op.ADD, self.base, acc, t)
                out.append(acc)
        return out

    # -- what is known across control flow -----------------------------------------------
    # A shape says what is known of a value holding matrices: for a matrix, which entries
    # may be non-zero and whether it is u * identity (``MShape``); for a struct or tuple,
    # the shapes of its fields (None for a field without matrices).
    def full(self, t: Type) -> Any:
        """The shape of a value of type ``t`` of which nothing is known."""
        if isinstance(t, StructType) and t.name == "Mueller":
            return (True,) * 16, False
        if isinstance(t, (StructType, TupleType)):
            parts = tuple(self.full(c) for c in components(t))
            return parts if any(p is not None for p in parts) else None
        return None

    def shape(self, v: Value) -> Any:
        if self.is_mueller(v):
            e = self.entries.get(v)
            nonzero = (True,) * 16 if e is None else tuple(x is not None for x in e)
            return nonzero, v in self.scalar
        return self.parts.get(v) or self.full(v.type)

    def assume(self, b: Builder, v: Value, shape: Any) -> None:
        """Record that ``v`` has ``shape`` (matrix entries are read from ``v`` itself)."""
        if shape is None:
            return
        if not self.is_mueller(v):
            self.parts[v] = shape
            return
        nonzero, scalar = shape
        entries = [b.op(Op.EXTRACT, self.base, v, index=i) if nz else None
                   for i, nz in enumerate(nonzero)]
        self.entries[v] = entries
        if scalar:
            self.scalar[v] = entries[0]

    def join(self, x: Any, y: Any) -> Any:
        if x is None:
            return None
        if len(x) == 2 and isinstance(x[1], bool):  # a matrix
            return tuple(p or q for p, q in zip(x[0], y[0])), x[1] and y[1]
        return tuple(self.join(p, q) for p, q in zip(x, y))

    def track(self, ins: Instr, b: Builder, ops: list[Value]) -> None:
        """Follow shapes into and out of structs and tuples (a BSDF sample's weight)."""
        r = ins.results[0] if len(ins.results) == 1 else None
        if r is None or self.is_mueller(r) and ins.op is not Op.EXTRACT:
            return
        if ins.op is Op.MAKE and self.full(r.type) is not None:
            self.parts[r] = tuple(self.shape(v) if self.full(v.type) is not None else None
                                  for v in ops)
        elif ins.op is Op.INSERT and ops[0] in self.parts:
            parts = list(self.parts[ops[0]])
            parts[ins.attrs["index"]] = self.shape(ops[1])
            self.parts[r] = tuple(parts)
        elif ins.op is Op.EXTRACT and ops[0] in self.parts:
            self.assume(b, r, self.parts[ops[0]][ins.attrs["index"]])

    def merge(self, ins: Instr, mapping: dict[Value, Value]) -> list[Instr]:
        """After an ``if``: a result has the zeros both branches agree on (so a dispatch
        over depolarizing BSDFs still yields a depolarizer)."""
        b = Builder(Block(), ins.loc)
        for k, r in enumerate(ins.results):
            if self.full(r.type) is not None:
                ys = [mapping.get(v, v) for v in (reg.instrs[-1].operands[k]
                                                  for reg in ins.regions)]
                shape = self.shape(ys[0])
                for y in ys[1:]:
                    shape = self.join(shape, self.shape(y))
                self.assume(b, r, shape)
        return b.block.instrs

    def loop(self, lift: Lift, ins: Instr, mapping: dict[Value, Value]) -> list[Instr]:
        """Lift a loop whose carried matrices keep known zeros: assume each starts as its
        initial value's shape, lift the body, and widen the assumption to what the body
        yields until it holds (as Dr.Jit removes constant loop state).  The path tracer's
        throughput thus stays a depolarizer in a scene of depolarizing BSDFs, and the Stokes
        frame rotations around them vanish."""
        original = ins.regions[0]
        inits = [mapping.get(v, v) for v in ins.operands]
        carried = {k: self.shape(v) for k, v in enumerate(inits)
                   if self.full(v.type) is not None}
        if not carried:  # nothing to assume: one pass, in place
            lift._block(original, mapping)
            for r in ins.results:
                r.type = lift.lift_type(r.type)
            return [ins]
        while True:
            body = clone_block(original, {})
            head = Builder(Block(), ins.loc)
            for k, shape in carried.items():
                a = body.args[k]
                a.type = lift.lift_type(a.type)
                self.assume(head, a, shape)
            lift._block(body, mapping)
            body.instrs[:0] = head.block.instrs
            ys = [mapping.get(v, v) for v in body.instrs[-1].operands[1:]]
            wider = {k: self.join(s, self.shape(ys[k])) for k, s in carried.items()}
            if wider == carried:
                break
            carried = wider
        ins.regions[0] = body
        for r in ins.results:
            r.type = lift.lift_type(r.type)
        after = Builder(Block(), ins.loc)
        for k, shape in carried.items():
            self.assume(after, ins.results[k], shape)
        return [ins, *after.block.instrs]

    # -- the ops -------------------------------------------------------------------------
    def rewrite(self, lift: Lift, ins: Instr, b: Builder, ops: list[Value]) -> Value | None:
        """Return the replacement of ``ins``'s result, or None to keep it."""
        base = self.base
        res_m = len(ins.results) == 1 and self.is_mueller(ins.result)
        op = ins.op
        if op is Op.BROADCAST and res_m:
            return self.from_scalar(b, self.splat(b, ops[0]))
        if op in (Op.SPEC_RGB, Op.SPEC_TABLE, Op.SPEC_MAKE, Op.SPEC_LAMBDA) and res_m:
            ins.results[0].type = base
            u = lift._rewrite(ins, b, ops)
            ins.results[0].type = self.type
            return self.from_scalar(b, u if u is not None else ins.result)
        if op in (Op.SPEC_AVG, Op.SPEC_MAX, Op.SPEC_SRGB, Op.SPEC_UNPOL):
            x = ops[0]
            if self.is_mueller(x):
                x = self.entry(b, x, 0, 0)
            if op is Op.SPEC_UNPOL:
                return x
            return lift._rewrite(ins, b, [x])
        if op is Op.SPEC_FROM:
            return self.from_scalar(b, ops[0])
        if op is Op.SPEC_DEPOL:
            return self.make(b, [ops[0]] + [None] * 15)
        if op is Op.SPEC_MUELLER:
            return self.make(b, [None if self.is_zero(v) else v for v in ops])
        if op is Op.SPEC_ENTRY:
            return self.entry(b, ops[0], ins.attrs["row"], ins.attrs["col"])
        if not res_m:
            return lift._rewrite(ins, b, ops)
        # -- arithmetic on Mueller matrices
        if op in ARITH_OPS or op in _ELEMENTWISE_ONLY or op is Op.SELECT:
            mats = [v for v in ops if self.is_mueller(v)]
            if all(v in self.scalar for v in mats):  # all u * identity: act on the u's
                args = [self.scalar.get(v, v) for v in ops]
                picked = (lift.spectral.select(b, ins, args)
                          if op is Op.SELECT and lift.spectral is not None else None)
                if picked is None:
                    picked = b.op(op, base, *args)
                return self.from_scalar(b, picked)
        if op in (Op.ADD, Op.SUB):
            x, y = self.get(b, ops[0]), self.get(b, ops[1])
            out: list[Value | None] = []
            for p, q in zip(x, y):
                if q is None:
                    out.append(p)
                elif p is None:
                    out.append(q if op is Op.ADD else b.op(Op.NEG, base, q))
                else:
                    out.append(b.op(op, base, p, q))
            return self.make(b, out)
        if op is Op.NEG:
            return self.make(b, [None if p is None else b.op(Op.NEG, base, p)
                                 for p in self.get(b, ops[0])])
        if op is Op.SELECT:
            x, y = self.get(b, ops[1]), self.get(b, ops[2])
            out = []
            for p, q in zip(x, y):
                if p is None and q is None:
                    out.append(None)
                else:
                    out.append(b.op(Op.SELECT, base, ops[0], self.zero(b) if p is None else p,
                                    self.zero(b) if q is None else q))
            return self.make(b, out)
        if op is Op.MUL or (op is Op.DIV and ops[1] in self.scalar):
            x, y = ops
            if op is Op.DIV or y in self.scalar or x in self.scalar:
                m, u = (y, self.scalar[x]) if x in self.scalar and op is Op.MUL \
                    else (x, self.scalar[y])
                return self.make(b, [None if p is None else b.op(op, base, p, u)
                                     for p in self.get(b, m)])
            return self.make(b, self.product(b, self.get(b, x), self.get(b, y)))
        if op in _ELEMENTWISE_ONLY:
            what = _ELEMENTWISE_ONLY[op]
            verb = what if not what.startswith("`") else f"apply {what} to"
            raise lift._fail(ins, f"cannot {verb} a polarized Spectrum (a Mueller matrix) in "
                             f"the `{self.model.name}` variant: that is defined on "
                             "unpolarized values only; use `unpolarized(s)` or put this "
                             "code inside `if const polarized { ... } else { ... }`")
        return None


class _Spectral:
    """The spectral variant's lowering of colours, for one kernel: its wavelengths and the
    constant tables (CIE 1931, D65, tabulated spectra' cells) it reads, placed at the
    kernel's top."""

    def __init__(self, model: ColorModel, loc: Any) -> None:
        from ...core import spectral as data  # numpy only: the measured curves and fits

        self.data = data
        self.model = model
        self.wavelengths: Value | None = None
        self.tables = Builder(Block(), loc)
        # what depends on the wavelengths alone (D65 at them), computed once where they are
        # set rather than in every loop iteration that needs it
        self.prelude = Builder(Block(), loc)
        self.set_at = 0
        self._d65: Value | None = None
        self._tables: dict[bytes, Value] = {}
        # reflectances by their coefficients: a select between two picks coefficients and
        # evaluates one sigmoid (a scene's per-instance colours are such selects)
        self.coeffs: dict[Value, list[Value]] = {}
        # tabulated spectra read from a buffer, by (buffer, offset): likewise picked by a select
        self.stored: dict[Value, tuple[Value, Value]] = {}

    def lam(self, ins: Instr) -> Value:
        if self.wavelengths is None:
            raise CompileError([Diagnostic(ins.loc, "a colour is used before the wavelengths "
                                           "are set: call `set_wavelengths` (or "
                                           "`sample_wavelengths`) first, in the kernel's "
                                           "top-level block")])
        return self.wavelengths

    def table(self, values: Any) -> Value:
        arr = np.asarray(values, np.float32)
        key = arr.tobytes()
        if key not in self._tables:
            self._tables[key] = self.tables.op(Op.TABLE, BufferType(F32),
                                               values=[float(x) for x in arr])
        return self._tables[key]

    # -- building blocks -----------------------------------------------------------------
    def vec(self, b: Builder, x: float) -> Value:
        return b.op(Op.BROADCAST, VecType(4), b.const(float(x), F32))

    def components(self, b: Builder, v: Value) -> list[Value]:
        return [b.op(Op.EXTRACT, F32, v, index=i) for i in range(4)]

    def sample_table(self, b: Builder, table: Value, lam: Value) -> Value:
        """Linear interpolation of a table on the 5 nm grid over [360, 830] nm at one
        wavelength; 0 outside (as Mitsuba's ``cie1931_xyz`` and ``d65``)."""
        d = self.data
        last = d.CIE_SAMPLES - 1
        step = (d.LAMBDA_MAX - d.LAMBDA_MIN) / last
        t = b.op(Op.MUL, F32, b.op(Op.SUB, F32, lam, b.const(d.LAMBDA_MIN, F32)),
                 b.const(1.0 / step, F32))
        i = b.op(Op.CAST, I32, b.op(Op.FLOOR, F32, t))
        i = b.op(Op.MIN, I32, b.op(Op.MAX, I32, i, b.const(0, I32)), b.const(last - 1, I32))
        f = b.op(Op.SUB, F32, t, b.op(Op.CAST, F32, i))
        v0 = b.op(Op.LOAD, F32, table, i)
        v1 = b.op(Op.LOAD, F32, table, b.op(Op.ADD, I32, i, b.const(1, I32)))
        v = b.op(Op.ADD, F32, v0, b.op(Op.MUL, F32, b.op(Op.SUB, F32, v1, v0), f))
        inside = b.op(Op.AND, BOOL, b.op(Op.GE, BOOL, lam, b.const(d.LAMBDA_MIN, F32)),
                      b.op(Op.LE, BOOL, lam, b.const(d.LAMBDA_MAX, F32)))
        return b.op(Op.SELECT, F32, inside, v, b.const(0.0, F32))

    def sample_spectrum(self, b: Builder, ins: Instr, values: Any) -> Value:
        table = self.table(values)
        lam = self.components(b, self.lam(ins))
        return b.op(Op.MAKE, VecType(4), *[self.sample_table(b, table, x) for x in lam])

    def sample_cells(self, b: Builder, table: Value, base: Value | None, lam: Value,
                     grid: tuple[float, float, int], lo: Value, hi: Value) -> Value:
        """A tabulated spectrum's cells (``spectral.Cells``; ``grid``: their start, width and
        count; at ``base`` in ``table``) at one wavelength: the cell's knot picks the line on
        its side, whose value there and slope give the interpolant exactly; 0 outside
        [lo, hi]."""
        start, width, count = grid
        t = b.op(Op.MUL, F32, b.op(Op.SUB, F32, lam, b.const(float(start), F32)),
                 b.const(1.0 / width, F32))
        j = b.op(Op.CAST, I32, t)  # truncates; saturates, NaN -> 0
        j = b.op(Op.MIN, I32, b.op(Op.MAX, I32, j, b.const(0, I32)),
                 b.const(count - 1, I32))
        k = b.op(Op.MUL, I32, j, b.const(self.data.CELL_FLOATS, I32))
        if base is not None:
            k = b.op(Op.ADD, I32, k, base)
        ref = b.op(Op.LOAD, F32, table, k)
        right = b.op(Op.GE, BOOL, lam, ref)
        at = b.op(Op.ADD, I32, k, b.op(Op.SELECT, I32, right, b.const(3, I32),
                                       b.const(1, I32)))
        v = b.op(Op.LOAD, F32, table, at)
        slope = b.op(Op.LOAD, F32, table, b.op(Op.ADD, I32, at, b.const(1, I32)))
        v = b.op(Op.ADD, F32, v, b.op(Op.MUL, F32, b.op(Op.SUB, F32, lam, ref), slope))
        inside = b.op(Op.AND, BOOL, b.op(Op.GE, BOOL, lam, lo), b.op(Op.LE, BOOL, lam, hi))
        return b.op(Op.SELECT, F32, inside, v, b.const(0.0, F32))

    def tabulated(self, b: Builder, ins: Instr, wl: Any, values: Any) -> Value:
        """A scene's tabulated spectrum (a constant of the specialized build) at the
        wavelengths: exact, from cells fitted to its knots (``spectral.tabulated_cells``)."""
        try:
            cells = self.data.tabulated_cells(wl, values)
        except ValueError as e:
            raise CompileError([Diagnostic(ins.loc, str(e))]) from None
        if cells is None:  # it lies outside 360..830 nm
            return self.vec(b, 0.0)
        table = self.table(cells.table.ravel())
        lo, hi = b.const(cells.lo, F32), b.const(cells.hi, F32)
        grid = (cells.start, cells.width, cells.count)
        lam = self.components(b, self.lam(ins))
        return b.op(Op.MAKE, VecType(4), *[self.sample_cells(b, table, None, x, grid, lo, hi)
                                           for x in lam])

    def stored_table(self, b: Builder, ins: Instr, buf: Value, offset: Value) -> Value:
        """A tabulated spectrum the generic build stores in ``buf`` (its ``PRM``) at
        ``offset``: lo, hi, then the 1 nm cells over [360, 830] (``spectral.tabulated_slot``)."""
        d = self.data
        grid = (d.LAMBDA_MIN, (d.LAMBDA_MAX - d.LAMBDA_MIN) / d.GENERIC_CELLS, d.GENERIC_CELLS)
        lo = b.op(Op.LOAD, F32, buf, offset)
        hi = b.op(Op.LOAD, F32, buf, b.op(Op.ADD, I32, offset, b.const(1, I32)))
        base = b.op(Op.ADD, I32, offset, b.const(2, I32))
        lam = self.components(b, self.lam(ins))
        out = b.op(Op.MAKE, VecType(4), *[self.sample_cells(b, buf, base, x, grid, lo, hi)
                                          for x in lam])
        self.stored[out] = (buf, offset)
        return out

    def sigmoid_poly(self, b: Builder, ins: Instr, c: list[Value]) -> Value:
        """Jakob & Hanika's model at the wavelengths: s(c0 l^2 + c1 l + c2), s(x) =
        1/2 + x / (2 sqrt(1 + x^2)); x is clamped so that x^2 stays finite."""
        out = self._sigmoid_poly(b, ins, c)
        self.coeffs[out] = list(c)
        return out

    def select(self, b: Builder, ins: Instr, ops: list[Value]) -> Value | None:
        """``select(c, s(a), s(b))`` of two reflectances as ``s(select(c, a, b))``, and of
        two stored tables as the table at the selected offset."""
        x, y = self.stored.get(ops[1]), self.stored.get(ops[2])
        if x is not None and y is not None and x[0] is y[0]:
            offset = x[1] if x[1] is y[1] else b.op(Op.SELECT, I32, ops[0], x[1], y[1])
            return self.stored_table(b, ins, x[0], offset)
        a, c = self.coeffs.get(ops[1]), self.coeffs.get(ops[2])
        if a is None or c is None:
            return None
        picked = [x if x is y else b.op(Op.SELECT, F32, ops[0], x, y) for x, y in zip(a, c)]
        return self.sigmoid_poly(b, ins, picked)

    def _sigmoid_poly(self, b: Builder, ins: Instr, c: list[Value]) -> Value:
        v4 = VecType(4)
        lam = self.lam(ins)
        cs = [b.op(Op.BROADCAST, v4, x) for x in c]
        x = b.op(Op.ADD, v4, b.op(Op.MUL, v4, b.op(Op.ADD, v4, b.op(Op.MUL, v4, cs[0], lam),
                                                   cs[1]), lam), cs[2])
        x = b.op(Op.MIN, v4, b.op(Op.MAX, v4, x, self.vec(b, -1e18)), self.vec(b, 1e18))
        r = b.op(Op.SQRT, v4, b.op(Op.ADD, v4, b.op(Op.MUL, v4, x, x), self.vec(b, 1.0)))
        half = self.vec(b, 0.5)
        return b.op(Op.ADD, v4, b.op(Op.MUL, v4, half, b.op(Op.DIV, v4, x, r)), half)

    def d65(self, b: Builder, ins: Instr) -> Value:
        """The D65 illuminant at the wavelengths (in the prelude, once per kernel)."""
        if self._d65 is None:
            self._d65 = self.sample_spectrum(self.prelude, ins, np.asarray(
                self.data.d65_table()) * self.data.D65_NORMALIZATION)
        return self._d65

    # -- the ops -------------------------------------------------------------------------
    def from_rgb(self, b: Builder, ins: Instr, ops: list[Value], illuminant: bool) -> Value:
        d = self.data
        v4 = VecType(4)
        consts = [_const_value(v) for v in ops]
        if all(c is not None for c in consts):
            rgb = np.asarray(consts[:3], np.float64)
            scale = consts[3] if len(consts) == 4 else 1.0
            if "spectrum" in ins.attrs:  # a tabulated spectrum the scene gave
                out = self.tabulated(b, ins, *ins.attrs["spectrum"])
            elif illuminant:
                coeffs, s = d.illuminant_from_rgb(rgb)
                out = b.op(Op.MUL, v4, self.sigmoid_poly(
                    b, ins, [b.const(float(x), F32) for x in coeffs]), self.d65(b, ins))
                scale *= s
            else:
                coeffs = d.rgb_to_coeffs(rgb)
                out = self.sigmoid_poly(b, ins, [b.const(float(x), F32) for x in coeffs])
            if scale != 1.0:
                out = b.op(Op.MUL, v4, out, self.vec(b, scale))
            return out
        if not all(isinstance(v.owner, Instr) and v.owner.op is Op.LOAD for v in ops):
            raise CompileError([Diagnostic(ins.loc, "the spectral variant upsamples constant "
                                           "colours and colours read from the scene's "
                                           "buffers only; this one is computed")])
        out = self.sigmoid_poly(b, ins, ops[:3])
        if illuminant:
            out = b.op(Op.MUL, v4, out, self.d65(b, ins))
        if len(ops) == 4:
            out = b.op(Op.MUL, v4, out, b.op(Op.BROADCAST, v4, ops[3]))
        return out

    def to_srgb(self, b: Builder, ins: Instr, s: Value) -> Value:
        """Mitsuba's spectral film: XYZ = mean over the wavelengths of cie(l) s(l) /
        CIE_Y_INTEGRAL, then linear sRGB."""
        d = self.data
        cie = np.asarray(d.cie_table(), np.float64)
        tables = [self.table(cie[:, k]) for k in range(3)]
        lam = self.components(b, self.lam(ins))
        vals = self.components(b, s)
        xyz = []
        for k in range(3):
            acc = None
            for x, v in zip(lam, vals):
                term = b.op(Op.MUL, F32, self.sample_table(b, tables[k], x), v)
                acc = term if acc is None else b.op(Op.ADD, F32, acc, term)
            xyz.append(b.op(Op.MUL, F32, acc, b.const(1.0 / (4.0 * d.CIE_Y_INTEGRAL), F32)))
        rgb = []
        for row in np.asarray(d.XYZ_TO_SRGB, np.float64):
            acc = None
            for w, v in zip(row, xyz):
                term = b.op(Op.MUL, F32, b.const(float(w), F32), v)
                acc = term if acc is None else b.op(Op.ADD, F32, acc, term)
            rgb.append(acc)
        return b.op(Op.MAKE, ins.type, *rgb)


def _const_value(v: Value) -> float | None:
    """The f32 value a ``const`` instruction gives ``v`` (as a Python float), else None."""
    ins = v.owner
    if isinstance(ins, Instr) and ins.op is Op.CONST and "value" in ins.attrs \
            and "trait" not in ins.attrs:
        return float(np.float32(ins.attrs["value"]))
    return None
