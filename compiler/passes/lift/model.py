"""The spectrum models: what ``Spectrum`` becomes in each variant (``n`` samples per value,
and a Mueller matrix of them when polarized), and the variants' names."""

from __future__ import annotations

from dataclasses import dataclass

from ...diagnostics import CompileError
from ...ir import F32, StructType, Type, VecType

VARIANTS = ("mono", "rgb", "spectral", "mono_polarized", "spectral_polarized")


@dataclass(frozen=True)
class SpectrumModel:
    """How a variant represents ``Spectrum``: ``n`` f32 samples per unpolarized value (1 = a
    plain ``f32``); when ``polarized``, a 4x4 Mueller matrix of such values (the struct
    ``%Mueller``, row-major fields ``m00 .. m33``)."""

    variant: str
    n: int
    traits: frozenset[str]
    polarized: bool = False

    def unpolarized(self, lanes: int = 1) -> Type:
        return F32.with_lanes(lanes) if self.n == 1 else VecType(self.n, lanes=lanes)

    def concrete(self, lanes: int = 1) -> Type:
        if self.polarized:
            return mueller_type(self.unpolarized(), lanes)
        return self.unpolarized(lanes)


MUELLER_FIELDS = tuple(f"m{i}{j}" for i in range(4) for j in range(4))


def mueller_type(entry: Type, lanes: int = 1) -> StructType:
    """The lifted polarized ``Spectrum``: 16 entries, row-major."""
    return StructType("Mueller", tuple((f, entry) for f in MUELLER_FIELDS), lanes=lanes)


MODELS = {
    "mono": SpectrumModel("mono", 1, frozenset({"mono"})),
    "rgb": SpectrumModel("rgb", 3, frozenset({"rgb"})),
    "spectral": SpectrumModel("spectral", 4, frozenset({"spectral"})),
    "mono_polarized": SpectrumModel("mono_polarized", 1, frozenset({"mono", "polarized"}),
                                    polarized=True),
    "spectral_polarized": SpectrumModel("spectral_polarized", 4,
                                        frozenset({"spectral", "polarized"}), polarized=True),
}


def model_for(variant: str) -> SpectrumModel:
    """The spectrum model of ``variant``, or a diagnostic naming the accepted variants."""
    if variant in MODELS:
        return MODELS[variant]
    raise CompileError(f"unknown variant `{variant}` (expected one of: {', '.join(VARIANTS)})")

