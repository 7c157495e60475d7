"""The scene's render kernel as rdsl text: ``stdlib/render/kernel.rdsl.in`` filled in.

This is the one place where Python writes rdsl.  The template holds every fixed line of the
kernel; :func:`kernel_source` computes its holes from the scene description and what
``flatten`` made of it: rdsl literals of the camera and film constants, the imports of the
plugins the scene uses, the integrator call, the AOV fields and one film weight per pixel a
sample reaches (so the film's filter is evaluated once per sample and axis).  The output is
a pure function of those inputs; tests/test_kernel_source.py compares it with the golden
texts under tests/golden/kernel_source/.

The plugins' files are the ones the scene's plugin registry found (runtime/plugins.py): the
kernel imports a stdlib plugin by its path (``import bsdf.diffuse;``) and a user plugin by its
file's name (``import velvet;`` for ``velvet.rdsl``), whose folder :func:`scene_plugins`
returns among the search paths to compile the kernel with.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
from string import Template
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import RGB, ColorModel
from ..plugins import PluginDecl, kernel_imports, stdlib_plugin
from .camera import camera_uniforms
from .film import film_reach, film_uniforms
from .integrators import IntegratorPlan, direct_samples, integrator_plan

if TYPE_CHECKING:
    from ...core.scene_spec import Instance
    from .renderer import SceneBuffers

__all__ = ["AOV_EXPRESSIONS", "kernel_source", "literal", "scene_plugins"]

TEMPLATE = Path(__file__).resolve().parents[2] / "stdlib" / "render" / "kernel.rdsl.in"
# AOV type -> rdsl expression of each channel, from the `Aov` struct `aov`
# (stdlib/render/aov.rdsl); `albedo` is a Spectrum, written by _aov_fields
AOV_EXPRESSIONS: dict[str, tuple[str, ...]] = {
    "depth": ("aov.depth",),
    "position": ("aov.position.x", "aov.position.y", "aov.position.z"),
    "geo_normal": ("aov.geo_normal.x", "aov.geo_normal.y", "aov.geo_normal.z"),
    "sh_normal": ("aov.sh_normal.x", "aov.sh_normal.y", "aov.sh_normal.z"),
    "uv": ("aov.uv.x", "aov.uv.y"),
}


def literal(value: Any, struct: str | None = None) -> str:
    """An rdsl literal for a number, a vector (list) or a struct (dict) named ``struct``."""
    if isinstance(value, dict):
        nested = {"basis": "Frame"}
        fields = ", ".join(f"{k}: {literal(v, nested.get(k))}" for k, v in value.items())
        return f"{struct} {{ {fields} }}"
    if isinstance(value, (list, tuple, np.ndarray)):
        return f"Vec{len(value)}(" + ", ".join(literal(float(x)) for x in value) + ")"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    text = repr(float(np.float32(value)))
    return text if ("." in text or "e" in text or "n" in text) else text + ".0"


@cache
def _template() -> list[str]:
    """The template's lines, without its own ``//#`` notes."""
    return [line for line in TEMPLATE.read_text().split("\n") if not line.startswith("//#")]


def fill(holes: dict[str, str]) -> str:
    """The template with ``holes`` substituted; a line that is a lone hole left empty
    (no extra imports) is dropped rather than left blank."""
    out = []
    for line in _template():
        name = line[1:] if line.startswith("$") else None
        if name is not None and name.isidentifier() and holes.get(name) == "":
            continue
        out.append(Template(line).substitute(holes))
    return "\n".join(out)


def scene_plugins(desc: Any, bsdfs: list[Instance], emitters: list[Instance],
                  textures: list[Instance]) -> tuple[list[str], list[Path]]:
    """The import names of the plugins of the scene's instances, and the search paths that
    find the user plugins among them (for ``jit``)."""
    decls: list[PluginDecl] = []
    for kind, names in (("bsdf", {x.plugin for b in bsdfs for x in [b, *b.children]}),
                        ("emitter", {e.plugin for e in emitters}),
                        ("texture", {t.plugin for t in textures})):
        for name in sorted(names):
            decl = getattr(desc, "plugins", {}).get(name)
            if decl is None or decl.kind != kind:
                decl = stdlib_plugin(kind, name)
            if decl is None:
                raise CompileError(f"{kind} `{name}`: no plugin file declares it")
            decls.append(decl)
    return kernel_imports(decls, Path(desc.path).resolve().parent)


def _imports(plan: IntegratorPlan, spectral: bool, plugins: list[str]) -> list[str]:
    """The modules the kernel needs beyond path tracing, the camera and the film (and the
    scene's ``plugins``)."""
    modules = ["spectral"] if spectral else []
    if plan.radiance is not None and plan.radiance.type == "direct":
        modules.append("render.direct")
    if plan.aovs:
        modules.append("render.aov")
    if plan.stokes is not None:
        modules.append("render.stokes")
    modules += sorted(plugins)
    return [f"import {m};" for m in modules]


def _radiance_call(plan: IntegratorPlan, bufs: SceneBuffers) -> str:
    """The kernel's line computing `L` (and, for AOVs, the `aov` struct)."""
    integ = plan.radiance
    lights = f"{bufs.nlight}, {bufs.lights.env}"
    args = "P, N, UV, F, G, LC, LT, T, EK, E, ENV"
    if integ is None:
        line = "    let L = Spectrum(0.0);"
    elif integ.type == "direct":
        es, bs = direct_samples(integ)
        hide = "true" if integ.params.get("hide_emitters") else "false"
        line = f"    let (L, r3) = direct_li(ray, r2, {es}, {bs}, {hide}, {lights}, {args});"
    else:
        line = (f"    let (L, r3) = path_li(ray, r2, {int(integ.params.get('max_depth', -1))}, "
                f"{int(integ.params.get('rr_depth', 5))}, {lights}, {args});")
    if plan.aovs:
        line += "\n    let aov = aov_sample(ray, P, N, UV, F, G, T);"
    if plan.stokes is not None:  # the Stokes vector in the sensor's frame (as Mitsuba)
        line += "\n    let Ls = stokes_sensor_frame(L, ray.d, cam.basis.t);"
    return line


def _aov_fields(plan: IntegratorPlan, channels: int, spectral: bool = False
                ) -> list[tuple[str, str]]:
    """(rdsl type, expression) of each FilmSample AOV field, in film channel order: the
    Stokes components S0..S3 of a ``stokes`` integrator as RGB each (Mitsuba's layout; the
    one value repeated in mono), then the AOVs."""
    fields = []
    if plan.stokes is not None:
        for i in range(4):
            s = f"mueller_entry(Ls, {i}, 0)"
            fields.append(("Vec3", f"to_srgb(Spectrum({s}) * wavelength_weight)" if spectral
                           else f"Vec3(mean({s}))"))
    for _, kind in plan.aovs:
        if kind == "albedo":  # a Spectrum; mono repeats its one value in R, G and B
            fields.append(("Vec3", "Vec3(mean(aov.albedo))") if channels == 1
                          else ("Vec3", "to_srgb(aov.albedo * wavelength_weight)") if spectral
                          else ("Spectrum", "aov.albedo"))
        else:
            fields += [("Float", e) for e in AOV_EXPRESSIONS[kind]]
    return fields


def _film_holes(film: dict[str, Any]) -> dict[str, str]:
    """The film's constants and its per-sample weights: ``m`` columns and ``m`` rows of
    pixels around the sample's, fields ``w0 .. w{2m-1}`` of FilmSample."""
    reach = film_reach(film)
    m = 2 * reach + 1
    weights = []
    for k in range(m):
        weights.append(f"    let wx{k} = k * film_axis_weight(film, pos.x, gx - n + {k});")
        weights.append(f"    let wy{k} = k * film_axis_weight(film, pos.y, gy - n + {k});")
    return {
        "film": literal(dict(film, spp=1), "Film"),
        "film_layout": literal(dict(film, spp=0), "Film"),
        "cells": str(film["grid_w"] * film["grid_h"]),
        "grid_w": str(film["grid_w"]), "grid_x": str(film["grid_x"]),
        "grid_y": str(film["grid_y"]),
        "reach": str(reach),
        "film_weights": "\n".join(weights),
        "weight_fields": ", ".join(f"w{k}: Float" for k in range(2 * m)),
        "weight_values": ", ".join(f"w{k}: wx{k}" if k < m else f"w{k}: wy{k - m}"
                                   for k in range(2 * m)),
    }


def kernel_source(desc: Any, bufs: SceneBuffers, bsdfs: list[Instance],
                  emitters: list[Instance], model: ColorModel = RGB) -> str:
    """The scene's render kernel in rdsl: constants of this scene, stdlib code for the rest.
    A spectral kernel samples its wavelengths first and gives the film linear sRGB."""
    spectral, channels = model.spectral, model.channels
    # a polarized L is a Mueller matrix: the film records the intensity (entry [0][0], the
    # first Stokes component for the unpolarized emitters), as Mitsuba's film does
    mono_pol = model.mono and model.polarized
    plan = integrator_plan(desc.integrator)
    plan.check_variant(model)
    plugins, _ = scene_plugins(desc, bsdfs, emitters, bufs.textures)
    aov_fields = _aov_fields(plan, channels, spectral)
    film = film_uniforms(desc.sensor.film, 1, channels=channels + len(plan.aov_channel_names()))
    seed_rng = (["    let (rng, u_wavelength) = next_1d(pcg32_seed(UInt64(seed), stream));",
                 "    let wavelength_weight = sample_wavelengths(u_wavelength);"] if spectral
                else ["    let rng = pcg32_seed(UInt64(seed), stream);"])
    return fill({
        "scene_name": Path(desc.path).name,
        "imports": "\n".join(_imports(plan, spectral, plugins)),
        "value_type": "Vec3" if spectral else "Unpolarized" if mono_pol else "Spectrum",
        "value": ("to_srgb(L * wavelength_weight)" if spectral else "unpolarized(L)"
                  if mono_pol else "L"),
        "aov_fields": "".join(f"aov{k}: {t}, " for k, (t, _) in enumerate(aov_fields)),
        "aov_values": "".join(f"aov{k}: {e} * k, " for k, (_, e) in enumerate(aov_fields)),
        "camera": literal(camera_uniforms(desc.sensor), "Camera"),
        "seed_rng": "\n".join(seed_rng),
        "radiance": _radiance_call(plan, bufs),
        **_film_holes(film),
    })
