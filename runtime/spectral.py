"""Host-side spectral math, numerically matching Mitsuba 3's spectral variants.

Everything here is numpy on float64; Mitsuba computes in float32 from the same float32 tables,
so results agree to about 1e-6 relative. The tables live in ``stdlib/data/spectra`` (see its
README for provenance) and are read on first use.

Conventions, as in Mitsuba 3.9 (``include/mitsuba/core/spectrum.h``, ``render/srgb.h``):

* Tabulated curves (CIE 1931, D65) are linear interpolants of 95 samples on 360..830 nm every
  5 nm and are 0 outside that range.
* A film in a spectral variant turns a path's 4-wavelength sample into linear sRGB as
  ``XYZ_TO_SRGB @ mean_i(xyz(l_i) * value_i * weight_i) / CIE_Y_INTEGRAL``.
* Reflectance RGB is upsampled with the Jakob & Hanika (2019) sigmoid-polynomial model:
  ``s(l) = sigmoid(c0 l^2 + c1 l + c2)`` with ``l`` in nanometres.
* RGB radiance (the ``d65`` spectrum plugin) is ``s(l) * scale * d65(l) * D65_NORMALIZATION``
  with ``scale = 2 max(rgb)`` and ``s`` fitted to ``rgb / scale``; see
  :func:`illuminant_from_rgb`.
"""

from __future__ import annotations

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


def resample(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A tabulated spectrum (increasing wavelengths ``lam``) on the 95-sample 5 nm grid.

    Mitsuba's ``irregular`` (and ``regular``) spectrum evaluates the linear interpolant of the
    pairs inside ``[lam[0], lam[-1]]`` and 0 outside; this samples that at 360, 365, .., 830.
    """
    lam = np.asarray(lam, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    grid = LAMBDA_MIN + 5.0 * np.arange(CIE_SAMPLES)
    inside = (grid >= lam[0]) & (grid <= lam[-1])
    return np.where(inside, np.interp(grid, lam, values), 0.0)


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


def spectrum_to_rgb_emission(lam: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The linear sRGB an RGB variant uses for a ``<spectrum>`` of pairs given as a radiance.

    As :func:`spectrum_to_rgb_reflectance` but without the D65 factor (the values are the
    emitted spectrum itself) and only clamped below at 0 (``bounded=false, d65=false``).
    """
    return np.maximum(_list_to_srgb(lam, values, under_d65=False), 0.0)
