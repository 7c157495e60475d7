"""The scene's integrator, as the render kernel calls it: which stdlib function computes the
radiance (``path_li`` in stdlib/render/path.rdsl, ``direct_li`` in direct.rdsl) and which AOV
channels (stdlib/render/aov.rdsl) follow it on the film.

Mitsuba 3's ``aov`` integrator writes the nested integrator's RGB as the image's base
channels (0 without one) and then one channel group per ``name:type`` entry of ``aovs``,
named as aov.cpp names them (``dd.y:depth`` -> ``dd.y.T``, ``nn:sh_normal`` ->
``nn.X``, ``nn.Y``, ``nn.Z``).  This module only parses and names; the per-sample values
are computed in rdsl.

Mitsuba 3's ``stokes`` integrator (integrators/stokes.cpp) nests exactly one integrator and,
in polarized variants, writes the Stokes vector of its estimate, turned into the sensor's
frame (stdlib/render/stokes.rdsl), as twelve channels ``S0.R, S0.G, S0.B, ..., S3.B`` after
the base ones (R = G = B in mono).  In unpolarized variants Mitsuba refuses it ("This
integrator should only be used in polarized mode!"), and so does ``check_variant`` here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...compiler.diagnostics import CompileError
from ...core.color import ColorModel

__all__ = ["AOV_TYPES", "INTEGRATORS", "STOKES_CHANNELS", "IntegratorPlan", "integrator_plan"]

INTEGRATORS = ("path", "direct", "aov", "stokes")
RADIANCE = ("path", "direct")
# AOV type -> its channels' suffixes (the kernel's rdsl expressions of them:
# runtime/render/kernel_source.py)
AOV_TYPES: dict[str, tuple[str, ...]] = {
    "depth": ("T",),
    "position": ("X", "Y", "Z"),
    "geo_normal": ("X", "Y", "Z"),
    "sh_normal": ("X", "Y", "Z"),
    "uv": ("U", "V"),
    "albedo": ("R", "G", "B"),
}
# the `stokes` integrator's channels, in Mitsuba's order (stokes.cpp `aov_names`)
STOKES_CHANNELS = tuple(f"S{i}.{c}" for i in range(4) for c in "RGB")


@dataclass
class IntegratorPlan:
    """What the render kernel computes per sample: the radiance integrator (None: black),
    the AOVs as (name, type) pairs, and whether a ``stokes`` integrator writes S0..S3
    (``stokes``: its XML node, for diagnostics)."""

    radiance: Any | None
    aovs: list[tuple[str, str]] = field(default_factory=list)
    stokes: Any | None = None

    def aov_channel_names(self) -> list[str]:
        """The channels after the base ones, as the EXR names them, in film order: the Stokes
        components first (as Mitsuba's stokes integrator inserts them), then the AOVs."""
        return ([*STOKES_CHANNELS] if self.stokes is not None else []) + \
            [f"{name}.{s}" for name, kind in self.aovs for s in AOV_TYPES[kind]]

    def check_variant(self, model: ColorModel) -> None:
        """A ``stokes`` integrator needs a polarized variant: an error at its XML otherwise."""
        if self.stokes is not None and not model.polarized:
            raise CompileError(
                f"stokes: the Stokes integrator needs a polarized variant (`mono_polarized` or "
                f"`spectral_polarized`); the `{model.name}` variant carries no polarization, so "
                "there are no S0..S3 channels to write and nothing is rendered (Mitsuba 3 "
                "refuses it too: \"This integrator should only be used in polarized mode!\"). "
                "Render with a polarized variant, or use the nested integrator directly.",
                self.stokes.loc)


def _check_radiance(integ: Any) -> None:
    if integ.type in ("aov", "stokes"):
        raise CompileError(f"{integ.type}: an `{integ.type}` integrator cannot be nested in "
                           "another one by the renderer yet", integ.loc)
    if integ.type not in RADIANCE:
        raise CompileError(f"integrator `{integ.type}` is not supported by the renderer yet "
                           f"(supported: {', '.join(INTEGRATORS)})", integ.loc)
    if integ.type == "direct":
        p = integ.params
        if p.get("shading_samples") is not None and (p.get("emitter_samples") is not None
                                                     or p.get("bsdf_samples") is not None):
            raise CompileError("direct: cannot specify both 'shading_samples' and "
                               "('emitter_samples' and/or 'bsdf_samples')", integ.loc)
        es, bs = direct_samples(integ)
        if es < 0 or bs < 0 or es + bs == 0:
            raise CompileError("direct: must have at least 1 BSDF or emitter sample "
                               "(and no negative counts)", integ.loc)


def direct_samples(integ: Any) -> tuple[int, int]:
    """``direct``'s (emitter_samples, bsdf_samples), defaulting to ``shading_samples`` (1)."""
    p = integ.params
    shading = p.get("shading_samples")
    shading = 1 if shading is None else int(shading)
    es, bs = p.get("emitter_samples"), p.get("bsdf_samples")
    return (shading if es is None else int(es)), (shading if bs is None else int(bs))


def integrator_plan(integ: Any) -> IntegratorPlan:
    """Parse the scene's integrator; unsupported ones raise a CompileError at their XML."""
    if integ.type == "stokes":
        nested = list(integ.children)
        if len(nested) != 1:  # the loader's schema already says so; kept for Plugin objects
            raise CompileError("stokes: must specify exactly one sub-integrator "
                               f"(got {len(nested)})", integ.loc)
        _check_radiance(nested[0])
        return IntegratorPlan(nested[0], stokes=integ)
    if integ.type != "aov":
        _check_radiance(integ)
        return IntegratorPlan(integ)
    nested = list(integ.children)
    if len(nested) > 1:
        raise CompileError("aov: the renderer supports at most one nested integrator "
                           f"(got {len(nested)})", integ.loc)
    for child in nested:
        _check_radiance(child)
    aovs: list[tuple[str, str]] = []
    for token in str(integ.params["aovs"]).split(","):
        token = token.strip()
        if not token:
            continue
        item = token.split(":")
        if len(item) != 2 or not item[0] or not item[1]:
            raise CompileError(f"aov: invalid AOV specification `{token}`: require "
                               "<name>:<type>", integ.loc)
        if item[1] not in AOV_TYPES:
            raise CompileError(f"aov: AOV type `{item[1]}` is not supported by the renderer "
                               f"(supported: {', '.join(AOV_TYPES)})", integ.loc)
        aovs.append((item[0], item[1]))
    return IntegratorPlan(nested[0] if nested else None, aovs)
