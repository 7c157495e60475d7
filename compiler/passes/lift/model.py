"""What ``Spectrum`` becomes in a variant, as IR types: ``n`` f32 samples per unpolarized
value (a plain ``f32`` when ``n`` is 1), and when polarized a 4x4 Mueller matrix of them.
The variants themselves (their names, ``n``, traits) are :mod:`rdsl.core.color`'s
:class:`~rdsl.core.color.ColorModel`; this module only turns one into types."""

from __future__ import annotations

from ....core.color import ColorModel
from ...ir import F32, StructType, Type, VecType

MUELLER_FIELDS = tuple(f"m{i}{j}" for i in range(4) for j in range(4))


def mueller_type(entry: Type, lanes: int = 1) -> StructType:
    """The lifted polarized ``Spectrum``: 16 entries, row-major."""
    return StructType("Mueller", tuple((f, entry) for f in MUELLER_FIELDS), lanes=lanes)


def unpolarized_type(model: ColorModel, lanes: int = 1) -> Type:
    """The lifted ``Unpolarized``: ``f32`` for one sample, else a vector of ``model.n``."""
    return F32.with_lanes(lanes) if model.n == 1 else VecType(model.n, lanes=lanes)


def concrete_type(model: ColorModel, lanes: int = 1) -> Type:
    """The lifted ``Spectrum``: the unpolarized type, or a Mueller matrix of it (the struct
    ``%Mueller``, row-major fields ``m00 .. m33``)."""
    if model.polarized:
        return mueller_type(unpolarized_type(model), lanes)
    return unpolarized_type(model, lanes)
