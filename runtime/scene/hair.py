"""What the loader resolves of Mitsuba 3's ``hair`` BSDF (src/bsdfs/hair.cpp): the absorption
comes from the pigment concentrations or from ``sigma_a``, never both, and the rdsl plugin's
``use_pigmentation`` (stdlib/bsdf/hair.rdsl) says which; Mitsuba's range checks of the
roughnesses and of the indices of refraction (they must differ; the ``ior`` kind makes them
positive), and rdsl's own of the concentrations and scale (not negative)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ...compiler.ir import Loc
from .errors import scene_error

PIGMENTS = {"eumelanin": 1.3, "pheomelanin": 0.2}  # Mitsuba's defaults (brown hair)


def resolve_hair(p: dict[str, Any], given: Callable[[str], bool], what: str,
                 loc: Callable[[str], Loc]) -> None:
    """Check the resolved parameters ``p`` and set ``use_pigmentation`` and the pigments'
    defaults (``given(name)``: whether the scene set ``name``)."""
    for k in ("longitudinal_roughness", "azimuthal_roughness"):
        if not 0.0 <= p[k] <= 1.0:
            raise scene_error(f"{what}: '{k}' is {p[k]:g}; a hair roughness lies in [0, 1]",
                              loc(k))
    if p["int_ior"] == p["ext_ior"]:
        raise scene_error(f"{what}: 'int_ior' and 'ext_ior' are both {p['int_ior']:g}; the "
                          "fiber's interior and exterior indices of refraction must differ",
                          loc("int_ior" if given("int_ior") else "ext_ior"))
    pigments = [k for k in PIGMENTS if given(k)]
    if given("sigma_a") and pigments:
        raise scene_error(f"{what}: give either 'sigma_a' or the pigment concentrations "
                          "('eumelanin', 'pheomelanin'), not both (they set the same "
                          "absorption)", loc(pigments[0]))
    for k in (*PIGMENTS, "scale"):
        if p[k] is not None and p[k] < 0.0:
            raise scene_error(f"{what}: '{k}' is {p[k]:g}; it must be >= 0 (a negative "
                              "absorption would add light)", loc(k))
    p["use_pigmentation"] = not given("sigma_a")
    for k, default in PIGMENTS.items():
        if p[k] is None:
            p[k] = default
