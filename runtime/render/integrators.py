"""The scene's integrator as the render kernel calls it: which integrator plugins run per
camera ray, and which AOV channels follow the radiance on the film.

An integrator is a plugin (``integrator NAME { fn sample(scene, ray, sampler) ... }``,
stdlib/render/integrator.rdsl), found like any other by the scene's plugin registry: the
stdlib's ``path``, ``direct``, ``aov`` and ``stokes`` (stdlib/integrator/) or a user's.  One
that takes a last argument ``nested: Spectrum`` wraps the integrator nested in it in the XML
(0 without one), as Mitsuba 3's ``aov`` and ``stokes`` do; the kernel runs the nested one
first and hands its estimate over.  Whichever returns ``(Spectrum, A)`` gives the AOVs: each
field of the struct ``A`` becomes channels, in order, named ``field`` (a Float),
``field.U``/``.V`` (Vec2), ``field.X``/``.Y``/``.Z`` (Vec3) or ``field.R``/``.G``/``.B``
(Spectrum).  Mitsuba's ``aov`` also writes its nested integrator's image (colour and alpha)
before its AOVs, as ``_arg_0.R``, ``.G``, ``.B``, ``.A`` (or under the nested integrator's
``name``).

An integrator may also define ``fn sample_valid(scene, ray, sampler) -> (Spectrum, Bool)``:
the same estimate and whether the sample is valid (Mitsuba's ``valid``), the alpha of a
film whose ``pixel_format`` has one (``rgba``, ``xyza``, ``luminance_alpha``).  The kernel
calls it only for such a film (an rgb film's kernel is unchanged); a wrapper's alpha is its
nested integrator's, and without ``sample_valid`` the alpha is whether the camera ray hits
a surface (0 with no radiance integrator: Mitsuba's ``aov`` alone).

Mitsuba's ``aov`` integrator names its channels itself: its ``aovs`` property (``name:type``
entries) picks fields of ``A`` by type and names them as aov.cpp does (``dd.y:depth`` ->
``dd.y.T``, ``nn:sh_normal`` -> ``nn.X``, ``nn.Y``, ``nn.Z``).  Mitsuba's ``stokes``
integrator writes the Stokes vector of its nested estimate as ``S0.R, S0.G, ..., S3.B``; in
unpolarized variants Mitsuba refuses it ("This integrator should only be used in polarized
mode!"), and so does :meth:`IntegratorPlan.check_variant`.  This module only plans and
names; the per-sample values are computed in rdsl.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...compiler.diagnostics import CompileError
from ...compiler.ir import F32, SpectrumType, StructType, Type, VecType
from ...core.color import ColorModel
from ...core.scene_spec import Instance

__all__ = ["AOV_TYPES", "AovChannel", "IntegratorPlan", "has_sample_valid",
           "integrator_instances", "integrator_plan"]

# Mitsuba's aov types -> the field of stdlib/integrator/aov.rdsl's `Aov`, and the channel
# suffixes aov.cpp gives them
AOV_TYPES: dict[str, tuple[str, ...]] = {
    "depth": ("T",),
    "position": ("X", "Y", "Z"),
    "geo_normal": ("X", "Y", "Z"),
    "sh_normal": ("X", "Y", "Z"),
    "uv": ("U", "V"),
    "albedo": ("R", "G", "B"),
    "dp_du": ("X", "Y", "Z"),
    "dp_dv": ("X", "Y", "Z"),
    "prim_index": ("I",),
    "shape_index": ("I",),
}
_SUFFIXES = {2: ("U", "V"), 3: ("X", "Y", "Z")}
POLARIZED_ONLY = ("stokes",)  # Mitsuba refuses these in unpolarized variants
# the integrators whose colour AOVs need the colour before the kernel's spectral weighting
MONO_RGB_ONLY = ("moment",)


@dataclass(frozen=True)
class AovChannel:
    """One AOV field of the integrator's struct as image channels: the field, its type and
    the channel names."""

    field: str
    type: Type
    names: tuple[str, ...]


@dataclass
class IntegratorPlan:
    """What the render kernel computes per sample: the radiance integrator (None: black),
    the integrator wrapping it (None: none), each a loader node with its plugin declaration
    (``.decl``), and the AOV channels of whichever returns AOVs."""

    radiance: Any | None
    wrapper: Any | None = None
    aovs: list[AovChannel] = field(default_factory=list)

    @property
    def aov_source(self) -> Any | None:
        """The integrator whose ``sample`` returns the AOVs."""
        return next((i for i in (self.wrapper, self.radiance)
                     if i is not None and aov_struct(i) is not None), None)

    @property
    def nested_image(self) -> str | None:
        """The name of the nested integrator's image that Mitsuba's ``aov`` writes before
        its AOVs, as channels ``NAME.R``, ``.G``, ``.B``, ``.A`` (its colour and ``valid``):
        the nested integrator's ``name`` attribute, else ``_arg_0``; None for other
        wrappers, a user's, or no nested integrator."""
        wrapper = self.wrapper
        if (wrapper is None or wrapper.type != "aov" or getattr(wrapper, "decl", None)
                is not None or self.radiance is None):
            return None
        return (wrapper.params.get("nested_names") or ["_arg_0"])[0]

    def aov_channel_names(self) -> list[str]:
        """The channels after the base ones, as the EXR names them, in film order (as
        aov.cpp: the nested integrator's image, then the AOVs)."""
        nested = self.nested_image
        image = [f"{nested}.{c}" for c in "RGBA"] if nested is not None else []
        return image + [n for c in self.aovs for n in c.names]

    def check_variant(self, model: ColorModel) -> None:
        """A ``stokes`` integrator needs a polarized variant: an error at its XML otherwise."""
        node = self.wrapper if self.wrapper is not None else self.radiance
        if node is not None and node.type in MONO_RGB_ONLY and (model.spectral or
                                                                model.polarized):
            raise CompileError(f"{node.type}: rdsl computes this integrator's XYZ moments in "
                               f"the `mono` and `rgb` variants only, not `{model.name}`",
                               node.loc)
        if node is not None and node.type in POLARIZED_ONLY and not model.polarized:
            raise CompileError(
                f"{node.type}: the Stokes integrator needs a polarized variant (`mono_polarized` "
                f"or `spectral_polarized`); the `{model.name}` variant carries no polarization, "
                "so there are no S0..S3 channels to write and nothing is rendered (Mitsuba 3 "
                "refuses it too: \"This integrator should only be used in polarized mode!\"). "
                "Render with a polarized variant, or use the nested integrator directly.",
                node.loc)


def _decl(integ: Any) -> Any:
    decl = getattr(integ, "decl", None)
    if decl is None:
        from ..plugins import stdlib_plugin

        decl = stdlib_plugin("integrator", integ.type)
    if decl is None:
        raise CompileError(f"unknown integrator `{integ.type}`: no plugin file declares "
                           "`integrator " + integ.type + " { ... }`", integ.loc)
    return decl


def integer_settings(integ: Any) -> set[str]:
    """``scene.params`` names of the integrators' ``Int`` and ``Bool`` params
    (``path.max_depth``): whole numbers, which have no derivative."""
    out = set()
    for node in [integ, *integ.children]:
        name = node.id or node.type
        out |= {f"{name}.{k}" for k, p in _decl(node).params().items()
                if p.type in ("Int", "Bool")}
    return out


def nests(integ: Any) -> bool:
    """Whether the integrator's ``sample`` takes the nested integrator's estimate."""
    params, _ = _decl(integ).signature("sample")
    return len(params) == 4


def has_sample_valid(integ: Any) -> bool:
    """Whether the integrator defines ``sample_valid``: its estimate and whether the sample
    is valid (Mitsuba's ``valid``, the film's alpha)."""
    try:
        _decl(integ).signature("sample_valid")
    except KeyError:
        return False
    return True


def aov_struct(integ: Any) -> StructType | None:
    """The struct of AOVs the integrator's ``sample`` returns beside the radiance, if any."""
    _, ret = _decl(integ).signature("sample")
    elems = getattr(ret, "elems", None)
    return elems[1] if elems is not None else None


def _channels(integ: Any, struct: StructType) -> list[AovChannel]:
    """Every field as channels, or the ones Mitsuba's ``aovs`` property picks and names
    (parsed by the loader into ``aov_list``: (name, type) pairs)."""
    fields = dict(struct.fields)
    if integ.type == "moment" and integ.decl is None:  # Mitsuba's names (moment.cpp)
        name = (integ.params.get("nested_names") or ["_arg_0"])[0]
        return [AovChannel(f, t, tuple(f"{pre}{name}.{c}" for c in "XYZ"))
                for (f, t), pre in zip(struct.fields, ("", "m2_"), strict=True)]
    picked = integ.params.get("aov_list")
    if picked is None:
        return [AovChannel(f, t, _names(f, t)) for f, t in struct.fields]
    for _, kind in picked:
        if kind not in fields:
            raise CompileError(f"{integ.type}: AOV type `{kind}` is not supported by the "
                               f"renderer (supported: {', '.join(fields)})", integ.loc)
    return [AovChannel(kind, fields[kind], tuple(f"{name}.{s}" for s in AOV_TYPES[kind]))
            for name, kind in picked]


def _suffixes(t: Type) -> tuple[str, ...]:
    if isinstance(t, SpectrumType):
        return ("R", "G", "B")
    if isinstance(t, VecType):
        return _SUFFIXES[t.n]
    return ()


def _names(name: str, t: Type) -> tuple[str, ...]:
    return (name,) if t == F32 else tuple(f"{name}.{s}" for s in _suffixes(t))


def integrator_plan(integ: Any) -> IntegratorPlan:
    """Plan the scene's integrator; what the renderer cannot run raises a CompileError at
    its XML."""
    nested = list(integ.children)
    if not nests(integ):
        if nested:
            raise CompileError(f"{integ.type}: this integrator nests no other one (its "
                               "`sample` takes no `nested: Spectrum`)", nested[0].loc)
        plan = IntegratorPlan(integ)
    else:
        if len(nested) > 1:
            raise CompileError(f"{integ.type}: the renderer supports at most one nested "
                               f"integrator (got {len(nested)})", integ.loc)
        if integ.type == "stokes" and len(nested) != 1:
            raise CompileError("stokes: must specify exactly one sub-integrator "
                               f"(got {len(nested)})", integ.loc)
        inner = nested[0] if nested else None
        if inner is not None:
            if nests(inner):
                raise CompileError(f"{inner.type}: an integrator that wraps another one "
                                   f"cannot be nested in `{integ.type}` by the renderer yet",
                                   inner.loc)
            if aov_struct(inner) is not None and aov_struct(integ) is not None:
                raise CompileError(f"{inner.type}: an integrator with AOVs cannot be nested "
                                   f"in `{integ.type}`, which writes its own", inner.loc)
        plan = IntegratorPlan(inner, integ)
    source = plan.aov_source
    if source is not None:
        plan.aovs = _channels(source, aov_struct(source))
    return plan


def integrator_instances(integ: Any) -> list[Instance]:
    """The scene's integrators (the nested one after its wrapper) as plugin instances for
    ``specialize``: the XML properties that set a declared ``param``."""
    from .declared import declared_instance

    out = []
    for node in [integ, *integ.children]:
        decl = _decl(node)
        if not decl.stdlib:
            out.append(declared_instance(node))
            continue
        declared = decl.params()
        params = {k: (bool(v) if declared[k].type == "Bool" else int(v)
                      if declared[k].type == "Int" else v)
                  for k, v in node.params.items() if k in declared and v is not None}
        out.append(Instance(node.type, params, node.id or node.type))
    return out
