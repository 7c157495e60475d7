"""Colors and spectra: ``rgb`` / ``spectrum`` values, ``.spd`` files and named conductors.

A :class:`Color` keeps what the scene said (RGB, or wavelength/value pairs) and its linear
sRGB projection, so that the RGB variant reads ``color.rgb`` and a spectral variant can sample
``color.wavelengths`` / ``color.values``.

Spectrum-to-RGB follows Mitsuba 3's ``spectrum_list_to_srgb`` with its tabulated CIE 1931
curves (rdsl.core.spectral): 1000 evenly spaced samples over 360..830 nm of the
piecewise-linear spectrum, reflectances seen under D65.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...compiler.ir import F32_OVERFLOW, Loc
from ...core import spectral
from .errors import scene_error

CIE_MIN = 360.0
CIE_MAX = 830.0

IOR_DIR = Path(__file__).resolve().parents[2] / "stdlib" / "data" / "ior"


@dataclass(frozen=True)
class Color:
    """A resolved color: linear sRGB plus, when the scene gave one, the sampled spectrum."""

    rgb: tuple[float, float, float]
    wavelengths: tuple[float, ...] | None = None
    values: tuple[float, ...] | None = None
    # the rgb variants' colour is ``rgb`` as given, not recomputed from the pairs (Mitsuba's
    # spectrum plugins d65, uniform and srgb)
    fixed_rgb: bool = False

    @staticmethod
    def gray(value: float) -> Color:
        v = float(value)
        return Color((v, v, v))

    @property
    def is_uniform(self) -> bool:
        return self.wavelengths is None and self.rgb[0] == self.rgb[1] == self.rgb[2]


def spectrum_to_xyz(wavelengths: np.ndarray, values: np.ndarray) -> np.ndarray:
    """CIE XYZ of a piecewise-linear spectrum (zero outside its range), scaled so that a unit
    spectrum has luminance Y ~ 1 (Mitsuba's normalisation)."""
    return np.linalg.solve(spectral.XYZ_TO_SRGB, spectral.spectrum_to_rgb_emission(
        np.asarray(wavelengths, np.float64), np.asarray(values, np.float64)))


def spectrum_to_srgb(wavelengths, values, bounded: bool = True) -> tuple[float, float, float]:
    """What Mitsuba 3's rgb variants make of wavelength:value pairs: a reflectance
    (``bounded``) is seen under D65 and clamped to [0, 1], anything else only clamped at 0
    (rdsl.core.spectral, with the tabulated CIE 1931 curves)."""
    wl, v = np.asarray(wavelengths, np.float64), np.asarray(values, np.float64)
    rgb = (spectral.spectrum_to_rgb_reflectance(wl, v) if bounded
           else spectral.spectrum_to_rgb_emission(wl, v))
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]))


# ---------------------------------------------------------------------------------------
# Parsing the XML values

_NUM_SPLIT = re.compile(r"[,\s]+")


# colours Mitsuba's rgb variants leave unbounded (a conductor's complex index of refraction)
UNBOUNDED = ("eta", "k")


def as_reflectance(color: Color, name: str) -> Color:
    """Wavelength:value pairs (or an .spd file) that set ``name`` outside an emitter, as
    Mitsuba 3's rgb variants take them: seen under D65 and clamped to [0, 1] (``eta`` and
    ``k`` only at 0).  The pairs stay for the spectral variants; a colour without pairs is
    returned as it is."""
    if color.wavelengths is None or color.fixed_rgb:
        return color
    wl, v = np.asarray(color.wavelengths, np.float64), np.asarray(color.values, np.float64)
    rgb = (spectral.spectrum_to_rgb_unbounded(wl, v) if name in UNBOUNDED
           else spectral.spectrum_to_rgb_reflectance(wl, v))
    return Color((float(rgb[0]), float(rgb[1]), float(rgb[2])), color.wavelengths, color.values)


def flat_emission(color: Color) -> Color:
    """A ``<spectrum>`` setting an emitter's radiance: pairs as they are; a constant v is the
    flat spectrum v, as Mitsuba 3 takes it (its rgb variants see v times the equal-energy
    white's linear sRGB, about (1.2, 0.95, 0.91) v, not the grey v; its spectral variants v at
    every wavelength, without D65)."""
    if color.wavelengths is not None:
        return color
    wl, vals = (360.0, 830.0), (float(color.rgb[0]), float(color.rgb[0]))
    return Color(spectrum_to_srgb(wl, vals, bounded=False), wl, vals)


def parse_float(tok: str, what: str, loc: Loc) -> float:
    """``float(tok)`` (a ValueError if it is no number), which must fit the kernels' 32-bit
    Float: a finite number that would become infinity there is an error at ``loc``."""
    v = float(tok)
    if math.isfinite(v) and abs(v) >= F32_OVERFLOW:
        raise scene_error(f"{what}: {tok.strip()} is too large for a 32-bit float (the largest "
                          "is 3.4028235e+38)", loc)
    return v


def parse_numbers(text: str, what: str, loc: Loc) -> list[float]:
    """Split ``"1, 2 3"`` into floats; a bad token is an error at ``loc``."""
    out = []
    for tok in _NUM_SPLIT.split(text.strip()):
        if not tok:
            continue
        try:
            out.append(parse_float(tok, what, loc))
        except ValueError:
            raise scene_error(f"{what}: cannot parse {tok!r} as a number (in {text!r})",
                              loc) from None
    return out


def parse_rgb(text: str, loc: Loc) -> Color:
    """``<rgb value="r, g, b">`` (or one value for gray); negative components are rejected."""
    vals = parse_numbers(text, "rgb", loc)
    if len(vals) == 1:
        vals = vals * 3
    if len(vals) != 3:
        raise scene_error(f"rgb: expected 3 values \"r, g, b\" (or 1), got {len(vals)} "
                          f"in {text!r}", loc)
    if any(not math.isfinite(v) or v < 0 for v in vals):
        raise scene_error(f"rgb: values must be finite and non-negative, got {text!r}", loc)
    return Color((vals[0], vals[1], vals[2]))


def _check_spectrum(wl: list[float], vals: list[float], what: str, loc: Loc) -> None:
    for i in range(1, len(wl)):
        if not wl[i] > wl[i - 1]:
            raise scene_error(f"{what}: wavelengths must be strictly increasing, but "
                              f"{wl[i]:g} nm follows {wl[i - 1]:g} nm", loc)
    for w, v in zip(wl, vals):
        if w <= 0 or not math.isfinite(w):
            raise scene_error(f"{what}: wavelength {w:g} nm is not positive", loc)
        if v < 0 or not math.isfinite(v):
            raise scene_error(f"{what}: value {v:g} at {w:g} nm is negative or not finite; "
                              "spectra must be non-negative", loc)


def parse_spectrum(text: str, loc: Loc, bounded: bool = True) -> Color:
    """``<spectrum value="0.5">`` or ``value="400:0.1, 500:0.4, 600:0.3"``."""
    text = text.strip()
    if ":" not in text:
        vals = parse_numbers(text, "spectrum", loc)
        if len(vals) != 1:
            raise scene_error("spectrum: expected one value or \"wavelength:value\" pairs, "
                              f"got {text!r}", loc)
        if vals[0] < 0:
            raise scene_error(f"spectrum: value {vals[0]:g} is negative; spectra must be "
                              "non-negative", loc)
        return Color.gray(vals[0])
    wl, vals = [], []
    for pair in re.split(r"\s*,\s*|\s+", text):
        if not pair:
            continue
        parts = pair.split(":")
        if len(parts) != 2:
            raise scene_error(f"spectrum: {pair!r} is not a \"wavelength:value\" pair", loc)
        try:
            wl.append(parse_float(parts[0], "spectrum", loc))
            vals.append(parse_float(parts[1], "spectrum", loc))
        except ValueError:
            raise scene_error(f"spectrum: cannot parse {pair!r} as \"wavelength:value\"",
                              loc) from None
    if len(wl) < 2:
        raise scene_error("spectrum: give at least two \"wavelength:value\" pairs", loc)
    _check_spectrum(wl, vals, "spectrum", loc)
    return Color(spectrum_to_srgb(wl, vals, bounded), tuple(wl), tuple(vals))


def read_spd(path: Path, loc: Loc) -> tuple[list[float], list[float]]:
    """Read an ``.spd`` file (``wavelength value`` per line, ``#`` comments)."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise scene_error(f"cannot read spectrum file '{path}': {e.strerror}", loc) from None
    wl, vals = [], []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        try:
            if len(parts) != 2:
                raise ValueError
            wl.append(parse_float(parts[0], f"spectrum file '{path}' line {n}", loc))
            vals.append(parse_float(parts[1], f"spectrum file '{path}' line {n}", loc))
        except ValueError:
            raise scene_error(f"spectrum file '{path}' line {n}: expected "
                              f"\"wavelength value\", got {line!r}", loc) from None
    if len(wl) < 2:
        raise scene_error(f"spectrum file '{path}' holds fewer than two samples", loc)
    _check_spectrum(wl, vals, f"spectrum file '{path}'", loc)
    return wl, vals


def spectrum_from_file(path: Path, loc: Loc, bounded: bool = True) -> Color:
    wl, vals = read_spd(path, loc)
    return Color(spectrum_to_srgb(wl, vals, bounded), tuple(wl), tuple(vals))


# ---------------------------------------------------------------------------------------
# Named conductors and dielectrics

def conductor_materials() -> list[str]:
    """The conductor names that ``material=`` accepts."""
    names = {p.name.split(".")[0] for p in IOR_DIR.glob("*.eta.spd")}
    return sorted(names | {"none"})


def conductor_ior(name: str, loc: Loc) -> tuple[Color, Color]:
    """(eta, k) of a named conductor, unbounded, as Mitsuba's ``complex_ior_from_file``."""
    if name == "none":  # Mitsuba: a perfect mirror
        return Color.gray(0.0), Color.gray(1.0)
    eta_path, k_path = IOR_DIR / f"{name}.eta.spd", IOR_DIR / f"{name}.k.spd"
    if not eta_path.is_file() or not k_path.is_file():
        raise scene_error(f"conductor material '{name}' is unknown; accepted: "
                          f"{', '.join(conductor_materials())}", loc)
    return spectrum_from_file(eta_path, loc, False), spectrum_from_file(k_path, loc, False)


# Mitsuba 3's named dielectric IORs (ior.h).
DIELECTRIC_IORS: dict[str, float] = {
    "vacuum": 1.0, "helium": 1.00004, "hydrogen": 1.00013, "air": 1.00028,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}


def lookup_ior(name: str, loc: Loc) -> float:
    """A named dielectric's index of refraction (case-insensitive, as in Mitsuba)."""
    key = name.strip().lower()
    if key not in DIELECTRIC_IORS:
        raise scene_error(f"unknown index of refraction '{name}'; give a number or one of: "
                          f"{', '.join(DIELECTRIC_IORS)}", loc)
    return DIELECTRIC_IORS[key]
