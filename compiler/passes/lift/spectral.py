"""The spectral lowering of colours, for one kernel (``n = 4``).

Spectral variants carry the four wavelengths of a sample as an implicit value:
``set_wavelengths(wl)`` in the kernel's top-level block defines it, and every colour after it
is evaluated there.  Colours become spectra as in Mitsuba 3:

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

from ....core.color import ColorModel
from ...diagnostics import CompileError, Diagnostic
from ...ir import BOOL, F32, I32, Block, BufferType, Builder, Instr, Op, Value, VecType


class Spectral:
    """The spectral variant's lowering of colours, for one kernel: its wavelengths and the
    constant tables (CIE 1931, D65, tabulated spectra' cells) it reads, placed at the
    kernel's top."""

    def __init__(self, model: ColorModel, loc: Any) -> None:
        from ....core import spectral as data  # numpy only: the measured curves and fits

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
            raise CompileError([Diagnostic(
                ins.loc, "the spectral variant upsamples constant colours and colours read "
                "from the scene's buffers only; this one is computed (in a plugin, from "
                "`Float` params: constants in the specialized build only, not with "
                "--no-specialize or --watch; make the colour a `Spectrum` param, which the "
                "runtime upsamples)")])
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
