"""The plugin kinds' interfaces: the functions each kind must define, with their
signatures.  :func:`check_integrator` checks an integrator's ``sample``, whose shape varies
(AOVs, a nested integrator); the checker compares the others with the table."""

from __future__ import annotations

from ..compiler.ir import BOOL, F32, SPECTRUM, StructType, TupleType, VecType
from .program import PluginInfo
from .types import err, quoted

PLUGIN_INTERFACES: dict[str, list[tuple[str, list[tuple[str, str]], str]]] = {
    "bsdf": [("eval", [("si", "Surface"), ("wo", "Vec3")], "Spectrum"),
             ("pdf", [("si", "Surface"), ("wo", "Vec3")], "Float"),
             ("sample", [("si", "Surface"), ("u1", "Float"), ("u2", "Vec2")], "BsdfSample")],
    # area lights are sampled by the integrator over the scene's triangles, so only the
    # emitted radiance is required of an emitter
    "emitter": [("eval", [("si", "Surface")], "Spectrum")],
    "texture": [("eval", [("si", "Surface")], "Spectrum")],
    # checked by check_integrator: `sample` may also take the nested integrator's estimate
    # and return AOVs beside the radiance
    "integrator": [],
}
# functions a plugin may leave out (the renderer then assumes a default:
# compiler/passes/specialize.py, OPTIONAL) but must declare with these signatures when it has
# them, since the scene's dispatch calls them so
OPTIONAL_INTERFACES: dict[str, list[tuple[str, list[tuple[str, str]], str]]] = {
    "bsdf": [("disperses", [], "Bool"), ("smooth", [], "Bool"),
             ("albedo_two_sided", [], "Bool")],
    # the one value of a texture that sets a Float parameter (a roughness, a blend weight)
    "texture": [("eval_1", [("si", "Surface")], "Float")],
}
INTEGRATOR_SAMPLE = "fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum"
INTEGRATOR_VALID = ("fn sample_valid(scene: Scene, ray: Ray, sampler: Sampler) "
                    "-> (Spectrum, Bool)")
AOV_FIELD_TYPES = "`Float`, `Vec2`, `Vec3` or `Spectrum`"


def check_integrator(pl: PluginInfo, structs: dict[str, StructType]) -> None:
    """An integrator's ``sample``: ``(scene: Scene, ray: Ray, sampler: Sampler)``, plus
    ``nested: Spectrum`` for one that wraps a nested integrator (Mitsuba's ``aov`` and
    ``stokes``), returning a ``Spectrum`` or ``(Spectrum, A)`` with ``A`` a struct of
    AOV fields."""
    fn = pl.fns.get("sample")
    if fn is None:
        raise err(f"integrator `{pl.name}` is missing the required function "
                  f"`{INTEGRATOR_SAMPLE}`", pl.decl.loc)
    scene, sampler = structs.get("Scene"), structs.get("Sampler")
    if scene is None or sampler is None:
        raise err(f"integrator `{pl.name}`: `Scene` and `Sampler` are not declared; add "
                  "`import render.integrator;`", pl.decl.loc)
    want = [scene, structs["Ray"], sampler]
    ret = fn.ret
    aovs = ret.elems[1] if isinstance(ret, TupleType) and len(ret.elems) == 2 else None
    radiance = ret.elems[0] if aovs is not None else ret
    if fn.param_types not in (want, want + [SPECTRUM]) or radiance != SPECTRUM or (
            aovs is not None and not isinstance(aovs, StructType)):
        raise err(f"`{pl.name}.sample` has the wrong signature: expected `"
                  f"{INTEGRATOR_SAMPLE}` (optionally with `nested: Spectrum` last, and "
                  f"returning `(Spectrum, A)` with AOVs in a struct `A`), found "
                  f"`{fn.signature()}`", fn.decl.loc)
    if isinstance(aovs, StructType):
        for fname, ftype in aovs.fields:
            if not (ftype in (F32, SPECTRUM) or (isinstance(ftype, VecType)
                                                 and ftype.elem == F32 and ftype.n < 4)):
                raise err(f"AOV field `{aovs.name}.{fname}` of `{pl.name}.sample` has type "
                          f"{quoted(ftype)}; an AOV is {AOV_FIELD_TYPES}", fn.decl.loc)
    _check_sample_valid(pl, want)


def _check_sample_valid(pl: PluginInfo, want: list) -> None:
    """The optional ``sample_valid``: the estimate and whether the sample is valid (the
    film's alpha, Mitsuba's ``valid`` of ``SamplingIntegrator::sample``)."""
    fn = pl.fns.get("sample_valid")
    if fn is not None and (fn.param_types != want or fn.ret != TupleType((SPECTRUM, BOOL))):
        raise err(f"`{pl.name}.sample_valid` has the wrong signature: expected "
                  f"`{INTEGRATOR_VALID}`, found `{fn.signature()}`", fn.decl.loc)
