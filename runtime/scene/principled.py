"""What the loader resolves of Mitsuba 3's ``principled`` BSDF (src/bsdfs/principled.cpp):
its index of refraction, given as ``eta`` or as ``specular`` (not both), becomes the rdsl
plugin's ``eta`` (stdlib/bsdf/principled.rdsl), with Mitsuba's float32 arithmetic and its
nudges away from index-matched transmission."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from .errors import scene_error


def _has(value: Any) -> bool:
    """Mitsuba's get_flag: a lobe is on when given as a texture or as a non-zero float."""
    return value is not None and not (isinstance(value, (int, float)) and value == 0)


def resolve_principled(p: dict[str, Any], given: Callable[[str], bool], what: str,
                       loc: Callable[[str], Loc]) -> None:
    """Replace ``specular`` by ``eta`` in the resolved parameters ``p`` (``given(name)``:
    whether the scene set ``name``), as Mitsuba's constructor does."""
    f32 = np.float32
    transmits = _has(p.get("spec_trans")) and given("spec_trans")
    if given("eta") and given("specular"):
        raise scene_error(f"{what}: give either 'eta' or 'specular', not both (they set the "
                          "same index of refraction)", loc("specular"))
    if given("eta"):
        eta = f32(p["eta"])
        if transmits and eta == 1:  # index-matched transmission is not plausible (Mitsuba)
            eta = f32(1.001)
        name = "eta"
    else:
        s = f32(p["specular"])
        if transmits and s == 0:
            s = f32(1e-3)
        eta = f32(2) / (f32(1) - np.sqrt(f32(0.08) * s)) - f32(1)
        name = "specular"
    if not (math.isfinite(float(eta)) and eta > 0):
        raise scene_error(f"{what}: '{name}' = {p[name]:g} gives no valid index of refraction "
                          "(eta must be positive; specular lies in [0, 12.5), usually [0, 1])",
                          loc(name))
    p["eta"] = float(eta)
    p.pop("specular", None)
