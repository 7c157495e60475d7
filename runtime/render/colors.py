"""Colours as the variant stores them: what the kernels read from the scene's buffers.

A constant colour parameter reaches the compiler as a
:class:`~rdsl.compiler.passes.specialize.SpectrumValue` (sRGB, the scene's tabulated
spectrum if it gave one, and whether it is emitted light); the compiler upsamples it.  Colours
the kernels read from buffers (emitter tables, bitmap texels) are stored already encoded:
linear sRGB in the mono and rgb variants, Jakob & Hanika coefficients in the spectral one
(see compiler/passes/lift/spectral.py), and for emitted light a scale beside them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import ColorModel
from ...core.scene_spec import SpectrumValue


def spectrum_value(value: Any, what: str, illuminant: bool = False, loc: Any = None
                   ) -> SpectrumValue | float:
    """A scene colour (``Color`` or a number) as a parameter value.  A number or a grey stays
    a number for everything but emitted light: a flat spectrum, whatever its value (a
    conductor's k = 3.9 too); for an emitter it is a grey light (D65-shaped in spectral
    builds), as in Mitsuba 3."""
    rgb = getattr(value, "rgb", None)
    if rgb is not None and not illuminant and getattr(value, "is_uniform", False):
        return float(rgb[0])  # a grey (or a <float>) is a flat spectrum, as Mitsuba's uniform
    if rgb is None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise CompileError(f"{what}: a texture is not supported here (give an rgb or a "
                               "spectrum)", loc)
        if not illuminant:
            return float(value)
        rgb = (float(value),) * 3
    wl = getattr(value, "wavelengths", None)
    samples = None if wl is None else (tuple(map(float, wl)), tuple(map(float, value.values)))
    return SpectrumValue(tuple(float(x) for x in rgb), samples, illuminant)


def emission_row(rgb: np.ndarray, model: ColorModel) -> tuple[np.ndarray, float]:
    """An emitted colour as an emitter table stores it: 3 floats and a scale (the rdsl
    ``illuminant(c0, c1, c2, scale)``)."""
    rgb = np.asarray(rgb, np.float64)
    if not model.spectral:
        return rgb, 1.0
    from ...core.spectral import illuminant_from_rgb

    coeffs, scale = illuminant_from_rgb(rgb)
    return np.asarray(coeffs, np.float64), float(scale)


def encode_texels(texels: np.ndarray, model: ColorModel) -> np.ndarray:
    """Reflectance texels (..., 3) as ``model`` stores them."""
    if not model.spectral:
        return texels
    from ...core.spectral import rgb_to_coeffs

    shape = texels.shape
    return np.asarray(rgb_to_coeffs(np.asarray(texels, np.float64).reshape(-1, 3)),
                      np.float32).reshape(shape)


def emission_texels(rgb: np.ndarray, model: ColorModel) -> np.ndarray:
    """Emitted colours (n, 3) as an environment map's texels store them: 4 floats each,
    read by ``illuminant(c0, c1, c2)`` and a scale (linear sRGB and 1 in mono and rgb;
    coefficients of ``rgb / scale`` and ``scale = 2 max(rgb)`` in spectral, as Mitsuba's
    envmap)."""
    rgb = np.asarray(rgb, np.float64).reshape(-1, 3)
    if not model.spectral:
        return np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1)
    from ...core.spectral import illuminant_from_rgb

    coeffs, scale = illuminant_from_rgb(rgb)
    return np.concatenate([np.asarray(coeffs, np.float64).reshape(-1, 3),
                           np.asarray(scale, np.float64).reshape(-1, 1)], axis=1)
