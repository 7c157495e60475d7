"""Mitsuba 3's spectrum plugins, ``<spectrum type="..." name="...">`` with nested properties:
``uniform``, ``d65``, ``blackbody``, ``regular``, ``irregular`` and ``srgb``.

Each becomes a :class:`Color` whose ``rgb`` is what Mitsuba's rgb variants see and whose
wavelength:value pairs are what its spectral variants sample, so the rest of the loader treats
it like any ``<spectrum>``. Mitsuba's rgb variants refuse ``blackbody``, ``regular`` and
``irregular``; rdsl takes their linear sRGB projection there instead.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from ...core import spectral
from .errors import scene_error
from .spectra import Color, _check_spectrum, parse_float, spectrum_to_srgb

# The grid tabulated plugins (d65, blackbody, srgb) are sampled on: every 5 nm of 360..830.
GRID = np.linspace(360.0, 830.0, 95)

# name -> {parameter: the tag it is given as}
PLUGINS: dict[str, dict[str, str]] = {
    "uniform": {"value": "float"},
    "d65": {"scale": "float"},
    "blackbody": {"temperature": "float", "wavelength_min": "float",
                  "wavelength_max": "float"},
    "regular": {"wavelength_min": "float", "wavelength_max": "float", "values": "string",
                "range": "string"},
    "irregular": {"wavelengths": "string", "values": "string"},
    "srgb": {"color": "rgb"},
}
REQUIRED = {"blackbody": ("temperature",), "regular": ("values",),
            "irregular": ("wavelengths", "values"), "srgb": ("color",)}


def _floats(text: str, what: str, loc: Loc) -> list[float]:
    try:
        return [parse_float(t, what, loc) for t in re.split(r"[,\s]+", text.strip()) if t]
    except ValueError:
        raise scene_error(f"{what}: cannot parse {text!r} as a list of numbers", loc) from None


def _tabulated(wl: np.ndarray, vals: np.ndarray, rgb: tuple[float, float, float] | None = None
               ) -> Color:
    wl_t, v_t = tuple(float(w) for w in wl), tuple(float(v) for v in vals)
    if rgb is None:
        return Color(spectrum_to_srgb(wl_t, v_t, False), wl_t, v_t)
    return Color(rgb, wl_t, v_t, fixed_rgb=True)


def _planck(wl_nm: np.ndarray, temperature: float) -> np.ndarray:
    """Mitsuba's ``blackbody``: spectral radiance in W / (m^2 sr nm)."""
    c, h, k = 2.99792458e8, 6.62607004e-34, 1.38064852e-23
    lam = wl_nm * 1e-9
    with np.errstate(over="ignore"):
        return 1e-9 * 2 * h * c * c / (lam ** 5 * np.expm1(h * c / (k * lam * temperature)))


# long: one branch per plugin, read as a table
def spectrum_plugin(ptype: str, props: dict[str, tuple[str, Any, Loc]], loc: Loc) -> Color:
    """The color of ``<spectrum type="ptype">`` whose nested properties are ``props``
    (name -> (tag, value, location))."""
    if ptype not in PLUGINS:
        raise scene_error(f"unknown spectrum plugin '{ptype}'; accepted: "
                          f"{', '.join(PLUGINS)}", loc)
    accepted = PLUGINS[ptype]
    for name, (tag, _, ploc) in props.items():
        if name not in accepted:
            raise scene_error(f"spectrum '{ptype}' has no parameter '{name}'; accepted: "
                              f"{', '.join(accepted)}", ploc)
        if accepted[name] == "float" and tag not in ("float", "integer"):
            raise scene_error(f"parameter '{name}' of spectrum '{ptype}' expects a <float>, "
                              f"got <{tag}>", ploc)
        if accepted[name] != "float" and tag != accepted[name]:
            raise scene_error(f"parameter '{name}' of spectrum '{ptype}' expects "
                              f"<{accepted[name]}>, got <{tag}>", ploc)
    for name in REQUIRED.get(ptype, ()):
        if name not in props:
            raise scene_error(f"spectrum '{ptype}' needs the parameter '{name}'", loc)
    val = {k: v for k, (_, v, _) in props.items()}
    what = f"spectrum '{ptype}'"
    if ptype == "uniform":
        v = float(val.get("value", 1.0))
        if v < 0:
            raise scene_error(f"{what}: value {v:g} is negative", loc)
        return Color((v, v, v), (360.0, 830.0), (v, v), fixed_rgb=True)
    if ptype == "d65":
        s = float(val.get("scale", 1.0))
        return _tabulated(GRID, spectral.d65(GRID) * spectral.D65_NORMALIZATION * s, (s, s, s))
    if ptype == "srgb":
        rgb = np.asarray(val["color"].rgb, np.float64)
        scale = max(1.0, 2.0 * float(rgb.max())) if rgb.max() > 1.0 else 1.0
        curve = spectral.eval_coeffs(spectral.rgb_to_coeffs(rgb / scale), GRID) * scale
        return _tabulated(GRID, curve, tuple(float(c) for c in rgb))
    if ptype == "blackbody":
        t = float(val["temperature"])
        if not (t > 0 and math.isfinite(t)):
            raise scene_error(f"{what}: temperature must be positive, got {t:g}", loc)
        lo, hi = float(val.get("wavelength_min", 360.0)), float(val.get("wavelength_max", 830.0))
        wl = np.linspace(lo, hi, max(2, int(round((hi - lo) / 5.0)) + 1))
        return _tabulated(wl, _planck(wl, t))
    if ptype == "regular":
        values = _floats(val["values"], what, loc)
        if "range" in val:
            lo, hi = _floats(val["range"], what, loc)[:2]
        else:
            lo, hi = float(val.get("wavelength_min", 360.0)), float(val.get("wavelength_max",
                                                                            830.0))
        wl = list(np.linspace(lo, hi, len(values)))
    else:
        wl, values = _floats(val["wavelengths"], what, loc), _floats(val["values"], what, loc)
        if len(wl) != len(values):
            raise scene_error(f"{what}: {len(wl)} wavelengths but {len(values)} values", loc)
    if len(values) < 2:
        raise scene_error(f"{what}: give at least two values", loc)
    _check_spectrum(wl, values, what, loc)
    return _tabulated(np.asarray(wl), np.asarray(values))
