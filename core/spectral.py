"""Host-side spectral math, numerically matching Mitsuba 3's spectral variants.

Everything here is numpy on float64; Mitsuba computes in float32 from the same float32 tables,
so results agree to about 1e-6 relative. The tables live in ``stdlib/data/spectra`` (see its
README for provenance) and are read on first use.

Conventions, as in Mitsuba 3.9 (``include/mitsuba/core/spectrum.h``, ``render/srgb.h``):

* Tabulated curves (CIE 1931, D65) are linear interpolants of 95 samples on 360..830 nm every
  5 nm and are 0 outside that range.
* A scene's tabulated spectrum is the linear interpolant of its knots, 0 outside them
  (``irregular``): :func:`tabulated`, which the kernels evaluate exactly from the cells of
  :func:`tabulated_cells` (specialized builds) or :func:`tabulated_slot` (generic builds).
* A film in a spectral variant turns a path's 4-wavelength sample into linear sRGB as
  ``XYZ_TO_SRGB @ mean_i(xyz(l_i) * value_i * weight_i) / CIE_Y_INTEGRAL``.
* Reflectance RGB is upsampled with the Jakob & Hanika (2019) sigmoid-polynomial model:
  ``s(l) = sigmoid(c0 l^2 + c1 l + c2)`` with ``l`` in nanometres.
* RGB radiance (the ``d65`` spectrum plugin) is ``s(l) * scale * d65(l) * D65_NORMALIZATION``
  with ``scale = 2 max(rgb)`` and ``s`` fitted to ``rgb / scale``; see
  :func:`illuminant_from_rgb`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

LAMBDA_MIN = 360.0
LAMBDA_MAX = 830.0
CIE_SAMPLES = 95

# Mitsuba's MI_CIE_Y_NORMALIZATION is 1 / CIE_Y_INTEGRAL. Mitsuba 3 uses this value, not the
# 106.856895 of PBRT (which is also what summing the 5 nm ybar table times 5 nm gives); a unit
# spectrum therefore has luminance 1.000999 in Mitsuba, and in this module.
CIE_Y_INTEGRAL = 106.7502593994140625

# Mitsuba's MI_CIE_D65_NORMALIZATION: scales the raw D65 table (100 at 560 nm) so that D65
# under the CIE curves has luminance ~1 (equals CIE_Y_INTEGRAL / 10568).
D65_NORMALIZATION = 1.0 / 98.99741751876255

# XYZ -> linear sRGB (Rec. 709 primaries, D65), the matrix of Mitsuba's xyz_to_srgb().
XYZ_TO_SRGB = np.array([
    [3.240479, -1.537150, -0.498535],
    [-0.969256, 1.875991, 0.041556],
    [0.055648, -0.204043, 1.057311],
])

# Mitsuba's sample_rgb_spectrum (Radziszewski et al., "An Improved Technique for Full Spectral
# Rendering"): an inverse-CDF warp of a sech^2 density centred on 538 nm.
_WAVE_CENTER = 538.0
_WAVE_A = 0.8569106254698279
_WAVE_B = 1.8275019724092267
_WAVE_INV_K = 138.88888888888889   # 1 / 0.0072
_WAVE_K = 0.0072
_WAVE_PDF = 0.003939804229326285
_WAVE_WEIGHT = 253.82              # Mitsuba's rounded 1 / _WAVE_PDF (253.8197...)

# srgb_model_fetch's constant term for exact white (+) and black (-) instead of +-infinity.
_GREY_LIMIT = 8192.0

# spectrum_list_to_srgb: a fixed Riemann sum over this many points of [360, 830].
_LIST_STEPS = 1000

DATA_DIR = Path(__file__).resolve().parents[1] / "stdlib" / "data" / "spectra"
RGB2SPEC_TABLE = DATA_DIR / "srgb_rgb2spec.npz"


def _read_csv(name: str) -> np.ndarray:
    table = np.loadtxt(DATA_DIR / name, delimiter=",", skiprows=1, dtype=np.float64)
    grid = LAMBDA_MIN + 5.0 * np.arange(CIE_SAMPLES)
    if table.shape[0] != CIE_SAMPLES or not np.array_equal(table[:, 0], grid):
        raise ValueError(f"{name}: expected {CIE_SAMPLES} rows on the 5 nm grid 360..830")
    return table[:, 1:]


@lru_cache(maxsize=1)
def _cie() -> np.ndarray:
    table = _read_csv("cie1931_xyz.csv")
    table.flags.writeable = False
    return table


@lru_cache(maxsize=1)
def _d65() -> np.ndarray:
    table = _read_csv("d65.csv")[:, 0]
    table.flags.writeable = False
    return table


@lru_cache(maxsize=1)
def _rgb2spec() -> tuple[np.ndarray, np.ndarray]:
    with np.load(RGB2SPEC_TABLE) as f:
        scale, data = f["scale"], f["data"]
    res = scale.shape[0]
    if data.shape != (3, res, res, res, 3):
        raise ValueError(f"{RGB2SPEC_TABLE.name}: data has shape {data.shape}")
    return scale.astype(np.float64), data.astype(np.float64)


def cie_table() -> np.ndarray:
    """The CIE 1931 2-degree colour matching functions, shape (95, 3): x, y, z every 5 nm."""
    return _cie().copy()


def d65_table() -> np.ndarray:
    """The raw CIE D65 relative spectral power table, shape (95,), 100 at 560 nm."""
    return _d65().copy()


def _interp_grid(table: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
    """Mitsuba's lookup on the 5 nm grid: linear between samples, 0 outside [360, 830]."""
    lam = np.asarray(lam, dtype=np.float64)
    t = (lam - LAMBDA_MIN) * ((CIE_SAMPLES - 1) / (LAMBDA_MAX - LAMBDA_MIN))
    inside = (lam >= LAMBDA_MIN) & (lam <= LAMBDA_MAX)
    i0 = np.clip(np.floor(np.where(inside, t, 0.0)), 0, CIE_SAMPLES - 2).astype(np.intp)
    w1 = t - i0
    if table.ndim == 2:
        w1, inside = w1[..., None], inside[..., None]
    value = (1.0 - w1) * table[i0] + w1 * table[i0 + 1]
    return np.where(inside, value, 0.0)


def cie_xyz(lam: np.ndarray | float) -> np.ndarray:
    """CIE 1931 xyz at wavelengths ``lam`` (nm), shape ``lam.shape + (3,)`` (Mitsuba's
    ``cie1931_xyz``)."""
    return _interp_grid(_cie(), lam)


def d65(lam: np.ndarray | float) -> np.ndarray:
    """The raw (un-normalised) D65 table at ``lam`` (nm); Mitsuba's ``cie_d65`` is this times
    :data:`D65_NORMALIZATION`."""
    return _interp_grid(_d65(), lam)


def rgb_to_coeffs(rgb: np.ndarray, table: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> np.ndarray:
    """Sigmoid-polynomial coefficients for linear sRGB reflectances, shape (..., 3).

    What Mitsuba 3.9's ``srgb_model_fetch`` returns: components are clamped to [0, 1] (NaN
    reads as 1, as the C ``min``/``max`` macros do). An exact grey ``v`` is solved in closed
    form, ``(0, 0, (v - 1/2) / sqrt(v (1 - v)))``, with +-8192 for white and black. Any other
    colour is a trilinear lookup as in ``rgb2spec_fetch``: the largest component (the last one
    on ties) picks the sub-table and is its ``scale`` axis, the other two divided by it are the
    x and y axes. ``table`` is an optional ``(scale, data)`` pair to use instead of the
    committed table.
    """
    scale, data = _rgb2spec() if table is None else table
    res = scale.shape[0]
    rgb = np.asarray(rgb, dtype=np.float64)
    rgb = np.where(rgb < 1.0, rgb, 1.0)
    rgb = np.where(rgb > 0.0, rgb, 0.0)
    big = 2 - np.argmax(rgb[..., ::-1], axis=-1)
    z = np.take_along_axis(rgb, big[..., None], -1)[..., 0]
    black = z <= 0.0
    inv = np.where(black, 0.0, (res - 1) / np.where(black, 1.0, z))
    x = np.take_along_axis(rgb, ((big + 1) % 3)[..., None], -1)[..., 0] * inv
    y = np.take_along_axis(rgb, ((big + 2) % 3)[..., None], -1)[..., 0] * inv
    xi = np.minimum(x.astype(np.intp), res - 2)
    yi = np.minimum(y.astype(np.intp), res - 2)
    zi = np.clip(np.searchsorted(scale, z, side="right") - 1, 0, res - 2)
    x1, y1 = (x - xi)[..., None], (y - yi)[..., None]
    z1 = ((z - scale[zi]) / (scale[zi + 1] - scale[zi]))[..., None]

    def at(dz: int, dy: int, dx: int) -> np.ndarray:
        return data[big, zi + dz, yi + dy, xi + dx]

    out = (((at(0, 0, 0) * (1 - x1) + at(0, 0, 1) * x1) * (1 - y1)
            + (at(0, 1, 0) * (1 - x1) + at(0, 1, 1) * x1) * y1) * (1 - z1)
           + ((at(1, 0, 0) * (1 - x1) + at(1, 0, 1) * x1) * (1 - y1)
              + (at(1, 1, 0) * (1 - x1) + at(1, 1, 1) * x1) * y1) * z1)
    out = np.where(black[..., None], data[0, 0, 0, 0], out)

    v = rgb[..., 0]
    grey = (v == rgb[..., 1]) & (v == rgb[..., 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        c2 = (v - 0.5) / np.sqrt(v * (1.0 - v))
    c2 = np.where(v <= 0.0, -_GREY_LIMIT, np.where(v >= 1.0, _GREY_LIMIT, c2))
    closed = np.stack([np.zeros_like(v), np.zeros_like(v), c2], axis=-1)
    return np.where(grey[..., None], closed, out)


def eval_coeffs(coeffs: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
    """The sigmoid-polynomial spectrum ``sigmoid(c0 l^2 + c1 l + c2)`` at ``lam`` (nm).

    ``coeffs`` (..., 3) broadcasts against ``lam``'s leading dimensions plus one trailing
    wavelength axis: coefficients (..., 3) with ``lam`` (..., n) give (..., n), with a scalar
    ``lam`` they give (...). As in
    ``srgb_model_eval``, an infinite ``c2`` gives the constant 0 or 1. The sigmoid is taken
    without overflow so the result stays in [0, 1] for any finite coefficients; a polynomial
    that is NaN (only from infinite or NaN coefficients) evaluates to 0.5.
    """
    c = np.asarray(coeffs, dtype=np.float64)
    lam = np.asarray(lam, dtype=np.float64)
    c0, c1, c2 = (c[..., k, None] for k in range(3))
    with np.errstate(over="ignore", invalid="ignore"):
        x = (c0 * lam + c1) * lam + c2
        s = 0.5 + 0.5 * x / np.hypot(1.0, x)
    s = np.where(np.isinf(x), 0.5 + 0.5 * np.sign(x), s)
    s = np.where(np.isnan(s), 0.5, s)
    s = np.where(np.isinf(c2), 0.5 + 0.5 * np.sign(c2), s)
    s = np.clip(s, 0.0, 1.0)
    return s[..., 0] if lam.ndim == 0 else s


def srgb_model_mean(rgb: np.ndarray) -> np.ndarray:
    """Mitsuba 3's one value of an sRGB reflectance in spectral variants (the ``srgb``
    texture's ``eval_1``, its ``mean()``: ``srgb_model_mean``): the mean of the upsampled
    spectrum at 16 wavelengths evenly spaced over [360, 830] nm.  ``rgb`` (..., 3) gives
    (...); the colour is rounded to float32 first, as Mitsuba stores it."""
    rgb = np.asarray(rgb, np.float32).astype(np.float64)
    return eval_coeffs(rgb_to_coeffs(rgb), np.linspace(LAMBDA_MIN, LAMBDA_MAX, 16)).mean(-1)


def illuminant_from_rgb(rgb: np.ndarray) -> tuple[np.ndarray, float | np.ndarray]:
    """Coefficients and scale of an RGB radiance in a spectral variant (Mitsuba's ``d65``).

    An ``<rgb>`` (or a float ``v``, which is the grey ``(v, v, v)``) given to an emitter becomes
    a ``d65`` texture that emits

        L(l) = eval_coeffs(coeffs, l) * scale * d65(l) * D65_NORMALIZATION,

    with ``scale = 2 max(rgb)`` and ``coeffs = rgb_to_coeffs(rgb / scale)`` (so the fitted
    reflectance peaks near 0.5, far from the sigmoid's saturation). A grey reads the table's
    (0.5, 0.5, 0.5) cell, the constant 0.5, so L is exactly ``v * d65(l) * D65_NORMALIZATION``.
    Black gives ``scale = 0`` (Mitsuba would divide by zero; the emission is 0 either way).
    Vectorised over leading dimensions; a single colour returns a float scale.
    """
    rgb = np.asarray(rgb, dtype=np.float64)
    scale = 2.0 * np.max(rgb, axis=-1)
    safe = np.where(scale > 0.0, scale, 1.0)[..., None]
    coeffs = rgb_to_coeffs(np.where(scale[..., None] > 0.0, rgb / safe, 0.0))
    return coeffs, (float(scale) if scale.ndim == 0 else scale)


def sample_wavelengths(u: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Four wavelengths (nm) and their weights from one uniform sample, shapes (..., 4).

    Mitsuba's ``sample_wavelength``: ``math::sample_shifted`` spreads ``u`` to ``u + i/4``
    (entries above 1 wrap by subtracting 1), then ``sample_rgb_spectrum`` warps each to
    ``538 - atanh(0.85691 - 1.82750 u) / 0.0072`` (inside [360.1, 829.7]) with weight
    ``253.82 cosh^2(0.0072 (l - 538))``, Mitsuba's rounding of 1 / :func:`wavelength_pdf`.
    """
    u = np.asarray(u, dtype=np.float64)[..., None] + np.arange(4) / 4.0
    u = np.where(u > 1.0, u - 1.0, u)
    lam = _WAVE_CENTER - np.arctanh(_WAVE_A - _WAVE_B * u) * _WAVE_INV_K
    weight = _WAVE_WEIGHT * np.cosh(_WAVE_K * (lam - _WAVE_CENTER)) ** 2
    return lam, weight


def wavelength_pdf(lam: np.ndarray | float) -> np.ndarray:
    """The density :func:`sample_wavelengths` draws each wavelength from (Mitsuba's
    ``pdf_rgb_spectrum``): ``0.0039398 / cosh^2(0.0072 (l - 538))`` on [360, 830], else 0."""
    lam = np.asarray(lam, dtype=np.float64)
    pdf = _WAVE_PDF / np.cosh(_WAVE_K * (lam - _WAVE_CENTER)) ** 2
    return np.where((lam >= LAMBDA_MIN) & (lam <= LAMBDA_MAX), pdf, 0.0)


def spectrum_to_srgb(values: np.ndarray, lam: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Linear sRGB of a wavelength sample, as a spectral film accumulates it, shape (..., 3).

    ``XYZ_TO_SRGB @ mean_i(xyz(l_i) * values_i * weight_i) / CIE_Y_INTEGRAL`` over the last
    axis: Mitsuba's ``ImageBlock::put`` -> ``spectrum_to_srgb`` with the path throughput
    already multiplied by the wavelength weight. In expectation over :func:`sample_wavelengths`
    a unit spectrum gives about (1.205, 0.948, 0.909) (equal-energy white), and the radiance
    :func:`illuminant_from_rgb` makes of an rgb gives back about that rgb.
    """
    v = np.asarray(values, dtype=np.float64) * np.asarray(weight, dtype=np.float64)
    xyz = np.mean(cie_xyz(lam) * v[..., None], axis=-2) / CIE_Y_INTEGRAL
    return xyz @ XYZ_TO_SRGB.T


# -- tabulated spectra ------------------------------------------------------------------------
#
# A scene's tabulated spectrum (a ``<spectrum>`` of wavelength:value pairs, a spectrum file, a
# named conductor's complex IOR) is Mitsuba's ``irregular`` spectrum: the linear interpolant of
# its knots, 0 outside them.  The spectral kernels evaluate it exactly from a table of cells:
# regular cells over the wavelength range, each holding at most one knot ``b`` and the lines on
# either side of it (5 floats a cell, see :class:`Cells`).

CELL_CAP = 4096  # most cells of a specialized build's table (knots closer than 470/4096 nm)
CELL_FLOATS = 5
GENERIC_CELLS = 470  # the generic build's cells: 1 nm over [360, 830]
GENERIC_SLOT = 2 + CELL_FLOATS * GENERIC_CELLS  # its PRM floats: lo, hi, then the cells


@dataclass(frozen=True)
class Cells:
    """A tabulated spectrum as a table of regular cells: ``count`` cells of ``width`` nm from
    ``start``.  Row j of ``table`` (float32, shape (count, 5)) is the cell's knot ``b`` (or
    one of its ends where it has none) and the lines left and right of it, each as its value
    at ``b`` and its slope: ``f(l) = vl + (l - b) sl`` for ``l < b``, ``vr + (l - b) sr``
    from ``b`` on.  The value is 0 outside [``lo``, ``hi``] (float32 bounds rounded inwards,
    so that a float32 wavelength is inside exactly when it lies between the first and last
    knot, and within 360..830 nm)."""

    start: float
    width: float
    lo: float
    hi: float
    table: np.ndarray

    @property
    def count(self) -> int:
        return int(self.table.shape[0])


def _knots(lam: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = np.asarray(lam, np.float64)
    v = np.asarray(values, np.float64)
    if w.ndim != 1 or w.shape != v.shape or not w.size or np.any(np.diff(w) <= 0):
        raise ValueError("a tabulated spectrum needs as many values as wavelengths, and the "
                         "wavelengths strictly increasing")
    return w, v


def _round_up(x: float) -> float:
    """The smallest float32 >= x (as a float)."""
    y = np.float32(x)
    return float(y) if float(y) >= x else float(np.nextafter(y, np.float32(np.inf)))


def _round_down(x: float) -> float:
    y = np.float32(x)
    return float(y) if float(y) <= x else float(np.nextafter(y, np.float32(-np.inf)))


def _bounds(w: np.ndarray) -> tuple[float, float]:
    """The float32 domain [lo, hi]: the knots' range within the visible 360..830 nm."""
    lo, hi = max(float(w[0]), LAMBDA_MIN), min(float(w[-1]), LAMBDA_MAX)
    return (_round_up(lo), _round_down(hi)) if lo <= hi else (1.0, 0.0)


def tabulated(lam: np.ndarray, values: np.ndarray, wl: np.ndarray | float) -> np.ndarray:
    """A tabulated spectrum (strictly increasing wavelengths ``lam``, ``values``) at ``wl``
    (nm): Mitsuba's ``irregular`` spectrum, the linear interpolant of the pairs, 0 outside
    [lam[0], lam[-1]] and (as the CIE curves, where spectral variants sample no wavelength)
    outside [360, 830].  What the spectral kernels compute, to float32 rounding."""
    w, v = _knots(lam, values)
    wl = np.asarray(wl, np.float64)
    inside = (wl >= max(w[0], LAMBDA_MIN)) & (wl <= min(w[-1], LAMBDA_MAX))
    return np.where(inside, np.interp(wl, w, v), 0.0)


def cell_table(lam: np.ndarray, values: np.ndarray, start: float, stop: float,
               count: int) -> np.ndarray:
    """The (count, 5) float32 cells of :class:`Cells` over [start, stop] for the interpolant
    of the knots, extended by its end values beyond them (the domain test zeroes it there).

    A cell with one knot strictly inside holds that knot, rounded up to float32 (so that
    ``l >= b`` splits float32 wavelengths as the knot does), and each side's line exactly
    (its value at the rounded knot, computed in float64): the table is then exact.  A cell
    with none holds its line, referred to the end where it is smaller (so that a value near
    0 keeps its relative precision).  A cell with several knots, where they are closer than
    the cells are wide, keeps the one whose two-piece interpolant through the cell's ends
    errs least at the others, which are dropped."""
    w, v = _knots(lam, values)
    x = start + (stop - start) * np.arange(count + 1) / count  # whole nm on the 1 nm grid
    x[-1] = stop
    slopes = np.concatenate([[0.0], np.diff(v) / np.diff(w), [0.0]])  # left of w[0]: 0
    f0, f1 = np.interp(x[:-1], w, v), np.interp(x[1:], w, v)
    first = np.searchsorted(w, x[:-1], side="right")  # the knots strictly inside a cell:
    last = np.searchsorted(w, x[1:], side="left")  # w[first:last]
    ref = np.where(f1 < f0, x[1:], x[:-1])
    left = slopes[np.searchsorted(w, 0.5 * (x[:-1] + x[1:]))]
    right = left.copy()
    one = last - first == 1
    ref[one] = w[first[one]]
    left[one], right[one] = slopes[first[one]], slopes[first[one] + 1]
    for j in np.flatnonzero(last - first > 1):
        inner = w[first[j]:last[j]]
        errs = []
        for c in inner:
            pieces = np.interp(inner, [x[j], c, x[j + 1]], [f0[j], np.interp(c, w, v), f1[j]])
            errs.append(np.abs(pieces - v[first[j]:last[j]]).max())
        c = float(inner[int(np.argmin(errs))])
        fc = float(np.interp(c, w, v))
        ref[j], left[j], right[j] = c, (fc - f0[j]) / (c - x[j]), (f1[j] - fc) / (x[j + 1] - c)
    at = np.interp(ref, w, v)
    rounded = np.array([_round_up(r) for r in ref])
    shift = rounded - ref
    return np.stack([rounded, at + shift * left, left, at + shift * right, right],
                    axis=1).astype(np.float32)


def tabulated_cells(lam: np.ndarray, values: np.ndarray) -> Cells | None:
    """A specialized build's table of a tabulated spectrum, exact (to float32 rounding): cells
    over its domain [lo, hi] no wider than the smallest spacing of the knots inside it, so
    that no cell holds two.  Knots closer than (hi - lo) / CELL_CAP, the cells' cap, make
    crowded cells, which keep one knot each (:func:`cell_table`).  None where the spectrum
    lies outside 360..830 nm (it is 0 there)."""
    w, v = _knots(lam, values)
    lo, hi = _bounds(w)
    if lo > hi:
        return None
    inner = w[(w > lo) & (w < hi)]
    gap = float(np.diff(inner).min()) if inner.size > 1 else hi - lo
    count = max(1, min(CELL_CAP, int(np.ceil((hi - lo) / gap)) if gap > 0 else 1))
    while count < CELL_CAP:  # float64 rounding may leave a knot pair in one cell
        x = lo + (hi - lo) * np.arange(count + 1) / count
        crowded = np.searchsorted(w, x[1:], "left") - np.searchsorted(w, x[:-1], "right")
        if crowded.max() <= 1:
            break
        count += 1
    width = (hi - lo) / count if hi > lo else 1.0
    return Cells(lo, width, lo, hi, cell_table(w, v, lo, hi, count))


def tabulated_slot(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A tabulated spectrum as the generic build stores it in ``PRM``: ``GENERIC_SLOT`` floats,
    the domain's lo and hi and the :func:`cell_table` of 470 cells of 1 nm over [360, 830],
    whatever the knots.  Exact unless a cell holds two knots strictly inside it (knots 1 nm
    apart or more never do; of the named conductors only `Te`, `Te-e` and `TiO2` have closer
    ones, 0.73 and 0.94 nm apart); a crowded cell keeps one knot (:func:`cell_table`)."""
    w, v = _knots(lam, values)
    lo, hi = _bounds(w)
    table = cell_table(w, v, LAMBDA_MIN, LAMBDA_MAX, GENERIC_CELLS)
    return np.concatenate([np.float32([lo, hi]), table.ravel()])


def generic_cells(slot: np.ndarray) -> Cells:
    """The :class:`Cells` a generic build reads from its ``PRM`` slot."""
    slot = np.asarray(slot, np.float32)
    return Cells(LAMBDA_MIN, (LAMBDA_MAX - LAMBDA_MIN) / GENERIC_CELLS, float(slot[0]),
                 float(slot[1]), slot[2:].reshape(GENERIC_CELLS, CELL_FLOATS))


def eval_cells(cells: Cells | None, wl: np.ndarray | float) -> np.ndarray:
    """``cells`` at wavelengths ``wl`` in the kernels' float32 arithmetic (0 for None)."""
    lam = np.asarray(wl, np.float32)
    if cells is None:
        return np.zeros(lam.shape)
    f32 = np.float32
    with np.errstate(invalid="ignore", over="ignore"):
        t = (lam - f32(cells.start)) * f32(1.0 / cells.width)
        j = np.clip(np.nan_to_num(t, nan=0.0, posinf=cells.count, neginf=0.0),
                    0, cells.count - 1).astype(np.intp)
    ref, vl, sl, vr, sr = (cells.table[j, k] for k in range(CELL_FLOATS))
    side = lam >= ref
    v = np.where(side, vr, vl) + (lam - ref) * np.where(side, sr, sl)
    inside = (lam >= f32(cells.lo)) & (lam <= f32(cells.hi))
    return np.where(inside, v, f32(0.0)).astype(np.float64)


def _list_to_srgb(lam: np.ndarray, values: np.ndarray, under_d65: bool) -> np.ndarray:
    """Mitsuba's ``spectrum_list_to_srgb`` before clamping: a 1000-point Riemann sum."""
    lam = np.asarray(lam, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    x = LAMBDA_MIN + np.arange(_LIST_STEPS) / (_LIST_STEPS - 1) * (LAMBDA_MAX - LAMBDA_MIN)
    inside = (x >= lam[0]) & (x <= lam[-1])
    y = np.where(inside, np.interp(x, lam, values), 0.0)
    w = cie_xyz(x)
    if under_d65:
        w = w * (d65(x) * D65_NORMALIZATION)[:, None]
    xyz = (w * y[:, None]).sum(axis=0) * ((LAMBDA_MAX - LAMBDA_MIN) / _LIST_STEPS)
    return XYZ_TO_SRGB @ (xyz / CIE_Y_INTEGRAL)


def spectrum_to_rgb_reflectance(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The linear sRGB an RGB variant uses for a ``<spectrum>`` of wavelength:value pairs
    given as a reflectance (any non-emissive texture).

    Mitsuba 3.9 (``spectrum_list_to_srgb(..., bounded=true, d65=true)``): the piecewise-linear
    spectrum (0 outside its range) times the normalised D65 illuminant, integrated against the
    CIE curves by a 1000-point sum over 360..830 nm, divided by :data:`CIE_Y_INTEGRAL`, mapped
    by :data:`XYZ_TO_SRGB` and clamped to [0, 1]. A unit reflectance gives ~(1, 1, 1).
    """
    return np.clip(_list_to_srgb(lam, values, under_d65=True), 0.0, 1.0)


def spectrum_to_rgb_unbounded(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """As :func:`spectrum_to_rgb_reflectance` but only clamped below at 0: what an RGB
    variant makes of a conductor's ``eta`` or ``k`` given as pairs (under D65, unbounded)."""
    return np.maximum(_list_to_srgb(lam, values, under_d65=True), 0.0)


def spectrum_to_rgb_emission(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The linear sRGB an RGB variant uses for a ``<spectrum>`` of pairs given as a radiance.

    As :func:`spectrum_to_rgb_reflectance` but without the D65 factor (the values are the
    emitted spectrum itself) and only clamped below at 0 (``bounded=false, d65=false``).
    """
    return np.maximum(_list_to_srgb(lam, values, under_d65=False), 0.0)
