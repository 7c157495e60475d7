"""The colour models: what a variant's ``Spectrum`` is, and what follows from it.

A variant name (``mono``, ``rgb``, ``spectral``, ``mono_polarized``, ``spectral_polarized``)
is looked up in :data:`MODELS` once, where the user gives it; the compiler and the runtime
then ask the :class:`ColorModel` (``.spectral``, ``.polarized``, ``.channels``, ...) and never
read the name again.  The compiler's types for a model live in ``compiler/passes/lift/model.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MODELS", "MONO", "MONO_POLARIZED", "RGB", "SPECTRAL", "SPECTRAL_POLARIZED",
           "VARIANTS", "ColorModel"]


@dataclass(frozen=True)
class ColorModel:
    """How a variant represents ``Spectrum``: ``n`` f32 samples per unpolarized value (1 = a
    plain ``f32``, 3 = RGB, 4 = four wavelengths); when ``polarized``, a 4x4 Mueller matrix
    of such values.  ``traits`` are the ``if const`` names that hold in it."""

    name: str
    n: int
    traits: frozenset[str]
    polarized: bool = False

    @property
    def spectral(self) -> bool:
        """Colours are sampled at wavelengths (upsampled from RGB, tabulated spectra exact)."""
        return "spectral" in self.traits

    @property
    def mono(self) -> bool:
        """Colours are one luminance value."""
        return "mono" in self.traits

    @property
    def channels(self) -> int:
        """The film's colour channels: Y in mono, linear sRGB otherwise."""
        return 1 if self.mono else 3


MONO = ColorModel("mono", 1, frozenset({"mono"}))
RGB = ColorModel("rgb", 3, frozenset({"rgb"}))
SPECTRAL = ColorModel("spectral", 4, frozenset({"spectral"}))
MONO_POLARIZED = ColorModel("mono_polarized", 1, frozenset({"mono", "polarized"}),
                            polarized=True)
SPECTRAL_POLARIZED = ColorModel("spectral_polarized", 4, frozenset({"spectral", "polarized"}),
                                polarized=True)

MODELS: dict[str, ColorModel] = {
    m.name: m for m in (MONO, RGB, SPECTRAL, MONO_POLARIZED, SPECTRAL_POLARIZED)}
VARIANTS: tuple[str, ...] = tuple(MODELS)
