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

import math
from functools import cache
from pathlib import Path
from string import Template
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...compiler.ir import SpectrumType, VecType
from ...core.color import RGB, ColorModel
from ..plugins import PluginDecl, kernel_imports, stdlib_plugin
from .film import film_format, film_reach, film_uniforms
from .integrators import IntegratorPlan, has_sample_valid, integrator_plan
from .sensors import sensor_struct

if TYPE_CHECKING:
    from ...core.scene_spec import Instance
    from .renderer import SceneBuffers

__all__ = ["SCENE_BUFFERS", "film_channels", "kernel_source", "literal",
           "scene_plugins"]

TEMPLATE = Path(__file__).resolve().parents[2] / "stdlib" / "render" / "kernel.rdsl.in"
ADJOINT = TEMPLATE.with_name("adjoint.rdsl.in")  # appended for scene.backward
# the buffers of a `Scene` (stdlib/render/integrator.rdsl), the kernel's arguments of the
# same names
SCENE_BUFFERS = ("P", "N", "UV", "F", "G", "LC", "LT", "T", "EK", "E", "ENV", "BV", "BI")
# the scene's sampler -> the `kind` of stdlib/render/integrator.rdsl's Sampler
SAMPLER_KINDS = {"independent": 0, "stratified": 1, "multijitter": 3, "orthogonal": 4,
                 "ldsampler": 6}


def batch_row(first: int, spp: int, seed: int, *more: int) -> np.ndarray:
    """``BATCH`` of ``render_sample`` and its kin (stdlib/render/kernel.rdsl.in): the first
    sample of the batch, the samples per pixel, the seed's 32 bits as an Int, then ``more``."""
    return np.array([first, spp, int(np.uint32(seed).view(np.int32)), *more], np.int32)


def sampler_kind(sampler: Any) -> int:
    """The Sampler `kind` of the scene's sampler (a stratified one without jitter: 2, an
    orthogonal one: 5)."""
    kind = SAMPLER_KINDS[sampler.type]
    if sampler.params.get("jitter") is False:
        return 5 if kind == 4 else 2  # stratum centres (multijitter's too)
    return kind


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
    f = float(np.float32(value))
    if not math.isfinite(f):  # no literal spells these: the prelude's functions do
        return "nan()" if math.isnan(f) else "infinity()" if f > 0 else "-infinity()"
    text = repr(f)
    return text if ("." in text or "e" in text) else text + ".0"


@cache
def _template(path: Path = TEMPLATE) -> list[str]:
    """The template's lines, without its own ``//#`` notes."""
    return [line for line in path.read_text().split("\n") if not line.startswith("//#")]


def fill(holes: dict[str, str], path: Path = TEMPLATE) -> str:
    """The template with ``holes`` substituted; a line that is a lone hole left empty
    (no extra imports) is dropped rather than left blank."""
    out = []
    for line in _template(path):
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
    integ = desc.integrator
    for kind, names in (("bsdf", {x.plugin for b in bsdfs for x in [b, *b.children]}),
                        ("emitter", {e.plugin for e in emitters}),
                        ("texture", {t.plugin for t in textures}),
                        ("integrator", {i.type for i in [integ, *integ.children]})):
        for name in sorted(names):
            decl = getattr(desc, "plugins", {}).get(name)
            if decl is None or decl.kind != kind:
                decl = stdlib_plugin(kind, name)
            if decl is None:
                raise CompileError(f"{kind} `{name}`: no plugin file declares it")
            decls.append(decl)
    return kernel_imports(decls, Path(desc.path).resolve().parent)


def _imports(spectral: bool, plugins: list[str]) -> list[str]:
    """The modules the kernel needs beyond the integrator API, the camera and the film: the
    scene's ``plugins`` (its integrators among them)."""
    modules = (["spectral"] if spectral else []) + sorted(plugins)
    return [f"import {m};" for m in modules]


def _radiance_call(plan: IntegratorPlan, bufs: SceneBuffers, weight: str | None = None,
                   alpha: bool = False) -> str:
    """The kernel's lines computing `L` (and, with AOVs, the struct `sample_aovs`): the
    scene handle, the sampler, then the integrators (the nested one first); ``weight``:
    the sensor's factor on the radiance (an irradiance meter's pi).  ``alpha``: also
    `valid`, the film's alpha (see :func:`_valid_call`)."""
    buffers = ", ".join(f"{b}: {b}" for b in SCENE_BUFFERS)
    lines = [f"    let scene = Scene {{ {buffers},",
             f"                         nemitter: {bufs.nlight}, env: {bufs.lights.env}, "
             "up: cam.basis.t };",
             "    let sampler = r2;"]
    radiance, wrapper = plan.radiance, plan.wrapper
    source = plan.aov_source
    if radiance is None:
        lines.append("    let L0 = Spectrum(0.0);")
    elif alpha and source is not radiance and has_sample_valid(radiance):
        lines.append(f"    let (L0, valid) = {radiance.type}.sample_valid(scene, ray, sampler);")
        alpha = False  # `valid` is set
    else:
        out = "(L0, sample_aovs)" if source is radiance else "L0"
        lines.append(f"    let {out} = {radiance.type}.sample(scene, ray, sampler);")
    if alpha:
        lines.append(_valid_call(radiance))
    if wrapper is None:
        lines.append("    let L = L0;")
    else:
        out = "(L, sample_aovs)" if source is wrapper else "L"
        lines.append(f"    let {out} = {wrapper.type}.sample(scene, ray, sampler, L0);")
    if weight is not None:
        last = lines[-1].replace("(L,", "(Lu,").replace("let L =", "let Lu =")
        lines[-1:] = [last, f"    let L = Lu * {weight};"]
    return "\n".join(lines)


def _valid_call(radiance: Any | None) -> str:
    """The line computing `valid` for an integrator without ``sample_valid`` (or one
    that returns AOVs): whether the camera ray hits a surface; none when the scene has no
    radiance integrator (Mitsuba's `aov` alone: alpha 0)."""
    return ("    let valid = false;" if radiance is None
            else "    let valid = scene.trace(ray).valid;")


def _aov_fields(plan: IntegratorPlan, channels: int, spectral: bool = False
                ) -> list[tuple[str, str]]:
    """(rdsl type, expression) of each FilmSample AOV field, in film channel order: a
    Spectrum AOV as RGB (the one value repeated in mono, sRGB of the sampled wavelengths in
    spectral), a Float, Vec2 or Vec3 one as one Float field per component."""
    fields = []
    if plan.nested_image is not None:  # aov.cpp's copy of the nested integrator's image
        fields += [_colour_field("L0", channels, spectral), ("Float", "select(valid, 1.0, 0.0)")]
    for aov in plan.aovs:
        e = f"sample_aovs.{aov.field}"
        if isinstance(aov.type, SpectrumType):
            fields.append(_colour_field(e, channels, spectral))
        elif isinstance(aov.type, VecType):
            fields += [("Float", f"{e}.{c}") for c in "xyzw"[:aov.type.n]]
        else:
            fields.append(("Float", e))
    return fields


def _colour_field(e: str, channels: int, spectral: bool) -> tuple[str, str]:
    """(rdsl type, expression) of the Spectrum ``e`` as an RGB film field: the one value
    repeated in mono, sRGB of the sampled wavelengths in spectral."""
    return (("Vec3", f"Vec3(mean({e}))") if channels == 1
            else ("Vec3", f"to_srgb({e} * wavelength_weight)") if spectral
            else ("Spectrum", e))


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
        "weight_stores": "\n".join(f"    S[{k} * ns + j] = w{'x' if k < m else 'y'}{k % m};"
                                   for k in range(2 * m)),
        "weight_fields": ", ".join(f"w{k}: Float" for k in range(2 * m)),
        "weight_values": ", ".join(f"w{k}: wx{k}" if k < m else f"w{k}: wy{k - m}"
                                   for k in range(2 * m)),
    }


def film_channels(desc: Any, model: ColorModel, derivative: bool = False) -> list[str]:
    """The channels the scene's film accumulates, in order: the colour in the variant's own
    channels (Y, or R, G, B), A if the film's ``pixel_format`` has alpha, the integrator's
    AOV channels, then, for a derivative, its colour channels (``d.R``...)."""
    base = ["Y"] if model.mono else ["R", "G", "B"]
    return base + ["A"] * film_format(desc.sensor.film, model.mono)[1] + \
        integrator_plan(desc.integrator).aov_channel_names() + \
        [f"d.{c}" for c in base if derivative]


def _adjoint_source(film: dict[str, Any], model: ColorModel, value_type: str,
                    holes: dict[str, str]) -> str:
    """``render_sample_loss`` (stdlib/render/adjoint.rdsl.in) for the scene's film: one
    line per pixel a sample reaches, adding its weight times D's value there; and the
    film-weight kernels, which take the render kernel's ``holes`` for the sample position.
    D holds one plane per channel (runtime/render/backward.py), so that every tap of a
    packet of neighbouring samples reads each channel at an offset of one index, q: one
    vector load each (compiler/backends/llvm_runs.py), where interleaved channels took
    a gather each."""
    n = film_reach(film)
    m, c, row = 2 * n + 1, 1 if model.mono else 3, film["grid_w"] + 2 * n
    plane = row * (film["grid_h"] + 2 * n)
    make = {"Vec3": "Vec3", "Unpolarized": "Unpolarized"}.get(value_type, "Spectrum")
    taps = []
    for dy in range(m):
        for dx in range(m):
            at = dy * row + dx
            px = ", ".join(f"D[q + {k * plane + at}]" for k in range(c))
            taps.append(f"    a = a + f.w{dx} * f.w{m + dy} * {make}({px});")
    return fill({**holes, "value_type": value_type, "pad_w": str(row),
                 "zero": f"{make}(0.0)", "taps": "\n".join(taps)}, ADJOINT)


def kernel_source(desc: Any, bufs: SceneBuffers, bsdfs: list[Instance],
                  emitters: list[Instance], model: ColorModel = RGB,
                  derivative: bool = False, adjoint: bool = False) -> str:
    """The scene's render kernel in rdsl: constants of this scene, stdlib code for the rest.
    A spectral kernel samples its wavelengths first and gives the film linear sRGB.
    ``derivative``: the film also gets the derivative of the radiance (``derivative(x)``,
    along the parameter tangent of a forward-mode build), as channels after the AOVs.
    ``adjoint``: with ``render_sample_loss`` after it, whose reverse-mode kernel
    ``scene.backward`` runs (stdlib/render/adjoint.rdsl.in)."""
    spectral, channels = model.spectral, model.channels
    # a polarized L is a Mueller matrix: the film records the intensity (entry [0][0], the
    # first Stokes component for the unpolarized emitters), as Mitsuba's film does
    mono_pol = model.mono and model.polarized
    plan = integrator_plan(desc.integrator)
    plan.check_variant(model)
    plugins, _ = scene_plugins(desc, bsdfs, emitters, bufs.textures)
    sensor, sensor_fields, sensor_module, sensor_weight = sensor_struct(desc.sensor)
    plugins += [sensor_module] if sensor_module else []
    aov_fields = _aov_fields(plan, channels, spectral)
    alpha = film_format(desc.sensor.film, model.mono)[1]
    if alpha:  # the film's alpha, right after the colour as in Mitsuba's film
        aov_fields.insert(0, ("Float", "select(valid, 1.0, 0.0)"))
    value_type = "Vec3" if spectral else "Unpolarized" if mono_pol else "Spectrum"
    value = ("to_srgb(L_ok * wavelength_weight)" if spectral else "unpolarized(L_ok)"
             if mono_pol else "L_ok")
    if derivative:
        aov_fields.append((value_type, f"derivative({value})"))
    film = film_uniforms(desc.sensor.film, 1,
                         channels=len(film_channels(desc, model, derivative)))
    seed_rng = (["    let (rng, u_wavelength) = next_1d(pcg32_seed(UInt64(seed), stream));",
                 "    let wavelength_weight = sample_wavelengths(u_wavelength);"] if spectral
                else ["    let rng = pcg32_seed(UInt64(seed), stream);"])
    holes = {
        "imports": "\n".join(_imports(spectral, plugins)),
        "value_type": value_type,
        "value": value,
        "aov_fields": "".join(f"aov{k}: {t}, " for k, (t, _) in enumerate(aov_fields)),
        "aov_values": "".join(f"aov{k}: {e} * k, " for k, (_, e) in enumerate(aov_fields)),
        "camera": literal(sensor_fields, sensor),
        "seed_rng": "\n".join(seed_rng),
        "radiance": _radiance_call(plan, bufs, sensor_weight,
                                   alpha or plan.nested_image is not None),
        "sampler_kind": str(sampler_kind(desc.sensor.sampler)),
        **_film_holes(film),
    }
    src = fill(holes)
    return src + "\n" + _adjoint_source(film, model, value_type, holes) if adjoint else src
