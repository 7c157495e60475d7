"""A scene's BSDFs as ``specialize`` instances: Mitsuba's resolved parameters mapped onto the
``param``s of the stdlib plugins, and the combinators (``twosided``, ``blendbsdf``, ``mask``).

The loader has resolved every Mitsuba parameter (defaults filled in, ``material`` turned into
``eta``/``k``, ``alpha`` copied to ``alpha_u``/``alpha_v``, ``eta = int_ior / ext_ior``).
Each one is passed to the rdsl plugin's parameter of the same name, after these conversions:
``distribution`` "ggx"/"beckmann" to 0/1, ``alpha_u``/``alpha_v`` to ``alpha``/``alpha_v``
(or to ``alpha`` alone where the plugin is isotropic and they agree), colors to RGB tuples and
textures to references.  A parameter the rdsl plugin does not have is an error unless it
holds Mitsuba's default, so nothing is dropped silently.

A combinator is an instance of the rdsl plugin ``mixture`` (``stdlib/bsdf/mixture.rdsl``)
whose Int parameters ``a``, ``b`` are the ids of its nested BSDFs among the scene's *leaves*
(``SceneSpec.bsdf_leaves``, dispatched by ``stdlib/render/bsdf_leaf.rdsl``).  One level of
nesting is supported, plus ``twosided`` around or inside ``blendbsdf`` and ``mask`` (which
commute with it: their ``twosided`` flag).
"""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path
from typing import Any

from ...compiler.diagnostics import CompileError
from ...compiler.passes.specialize import Instance
from ..scene.schema import spec_for
from .colors import spectrum_value

STDLIB = Path(__file__).resolve().parents[2] / "stdlib"
# Mitsuba plugin -> rdsl file under stdlib/
BSDF_PLUGINS = {"diffuse": "bsdf.diffuse", "roughconductor": "bsdf.roughconductor",
                "conductor": "bsdf.conductor", "dielectric": "bsdf.dielectric",
                "thindielectric": "bsdf.thindielectric", "plastic": "bsdf.plastic",
                "roughplastic": "bsdf.roughplastic", "roughdielectric": "bsdf.roughdielectric",
                "mixture": "bsdf.mixture", "polarizer": "bsdf.polarizer",
                "retarder": "bsdf.retarder"}
COMBINATORS = ("twosided", "blendbsdf", "mask")  # Mitsuba's, all rdsl's `mixture`
LEAF_PARAMS = ("a", "b")  # the mixture's parameters that hold leaf ids
# every parameter of the mixture_*_buffers functions (which have no defaults)
MIXTURE = {"a": 0, "b": 0, "weight": 0.0, "null": 0.0, "twosided": False, "by_side": False}
DISTRIBUTIONS = {"ggx": 0, "beckmann": 1}
TRANSMISSIVE = ("dielectric", "thindielectric", "roughdielectric", "polarizer", "retarder")
# what a polarizing plugin does in an unpolarized render (as Mitsuba 3)
UNPOLARIZED_BEHAVIOUR = {
    "polarizer": "a neutral filter that transmits 50% of the light (times its transmittance)",
    "retarder": "fully transparent: it transmits all light unchanged"}


def polarization_warnings(desc: Any, variant: str) -> list[str]:
    """Warnings for plugins whose meaning is polarization, in an unpolarized variant."""
    if variant.endswith("_polarized"):
        return []
    out, seen = [], set()
    todo = [shape.bsdf for shape in desc.shapes if getattr(shape, "bsdf", None) is not None]
    while todo:
        plugin = todo.pop(0)
        todo += plugin.children
        if id(plugin) in seen:
            continue
        seen.add(id(plugin))
        if plugin.type in UNPOLARIZED_BEHAVIOUR:
            out.append(f"{plugin.loc or desc.path}: warning: {_where(plugin)} has no effect on "
                       f"polarization in the unpolarized `{variant}` variant; it acts as "
                       f"{UNPOLARIZED_BEHAVIOUR[plugin.type]} (as in Mitsuba 3). Render with "
                       "`mono_polarized` or `spectral_polarized` to polarize light.")
    return out


def dispersion_warnings(desc: Any, variant: str) -> list[str]:
    """Warnings for dispersive dielectrics (Cauchy B terms) in a variant without wavelengths."""
    if variant.removesuffix("_polarized") == "spectral":
        return []
    out = []
    todo = [shape.bsdf for shape in desc.shapes if getattr(shape, "bsdf", None) is not None]
    seen: set[int] = set()
    while todo:
        plugin = todo.pop(0)
        todo += plugin.children
        if id(plugin) in seen:
            continue
        seen.add(id(plugin))
        if plugin.params.get("int_cauchy_b") or plugin.params.get("ext_cauchy_b"):
            out.append(f"{plugin.loc or desc.path}: warning: {_where(plugin)} is dispersive "
                       f"(Cauchy B term), which only spectral variants render; the `{variant}` "
                       "variant uses its IOR at 589.3 nm (the sodium D line) for every colour.")
    return out


@cache
def plugin_params(plugin: str) -> dict[str, str]:
    """The rdsl plugin's ``param`` names and types, read from its source."""
    src = (STDLIB / (BSDF_PLUGINS[plugin].replace(".", "/") + ".rdsl")).read_text()
    return dict(re.findall(r"^\s*param\s+(\w+)\s*:\s*(\w+)", src, re.MULTILINE))


def _where(plugin: Any) -> str:
    return f"bsdf `{plugin.type}`" + (f" (id '{plugin.id}')" if plugin.id else "")


def _value(plugin: Any, name: str, value: Any, textures: Any) -> Any:
    """A parameter value as ``specialize`` takes it."""
    what = f"{plugin.type}.{name}"
    if getattr(value, "category", None) == "texture":
        if textures is None or plugin_params(plugin.type).get(name) != "Texture":
            raise CompileError(f"{_where(plugin)}: a texture for `{name}` is not supported by "
                               "the renderer yet", plugin.loc)
        return textures.ref(value, what)
    if getattr(value, "rgb", None) is not None:
        return spectrum_value(value, what, loc=plugin.loc)
    if isinstance(value, (bool, int, float)):
        return value
    raise CompileError(f"{_where(plugin)}: cannot pass `{name}` = {value!r} to the rdsl "
                       "plugin", plugin.loc)


def _is_default(plugin: Any, name: str, value: Any) -> bool:
    spec = spec_for("bsdf", plugin.type)
    p = spec.params.get(name) if spec is not None else None
    if p is None or value is None:
        return value is None
    rgb = getattr(value, "rgb", None)
    if rgb is not None and isinstance(p.default, (int, float)):
        return all(float(c) == float(p.default) for c in rgb)
    return value == p.default


def leaf_instance(plugin: Any, textures: Any = None) -> Instance:
    """One non-combinator BSDF."""
    if plugin.type not in BSDF_PLUGINS or plugin.type == "mixture":
        supported = ", ".join(sorted([*BSDF_PLUGINS, *COMBINATORS]))
        raise CompileError(f"bsdf `{plugin.type}` is not supported by the renderer yet "
                           f"(supported: {supported})", plugin.loc)
    ours = plugin_params(plugin.type)
    p = dict(plugin.params)
    p.pop("material", None)  # resolved into eta / k
    if "int_ior" in p:
        p.pop("eta", None)   # derived: int_ior / ext_ior
    if p.get("distribution") is not None:
        p["distribution"] = DISTRIBUTIONS[p["distribution"]]
    if "alpha_u" in p:
        au, av = p.pop("alpha_u"), p.pop("alpha_v")
        if "alpha_v" in ours:
            p["alpha"], p["alpha_v"] = au, av
        elif au != av:
            raise CompileError(f"{_where(plugin)}: anisotropic roughness (alpha_u != alpha_v) "
                               f"is not supported by the rdsl plugin `{plugin.type}` yet",
                               plugin.loc)
        else:
            p["alpha"] = au
    params: dict[str, Any] = {}
    for name, value in p.items():
        if name in ours:
            if value is not None:
                params[name] = _value(plugin, name, value, textures)
        elif not _is_default(plugin, name, value):
            raise CompileError(f"{_where(plugin)}: parameter `{name}` = {value!r} is not "
                               f"supported by the rdsl plugin (it has: {', '.join(ours)})",
                               plugin.loc)
    return Instance(plugin.type, params, plugin.id or plugin.type)


def _unwrap_twosided(plugin: Any) -> tuple[Any, bool]:
    """``plugin`` or, for a twosided of one BSDF, the BSDF it wraps and True."""
    if plugin.type == "twosided" and len(plugin.children) == 1:
        return plugin.children[0], True
    return plugin, False


def _nested_error(outer: Any, inner: Any) -> CompileError:
    return CompileError(f"{_where(outer)}: a nested `{inner.type}` is not supported by the "
                        "renderer yet (one level of nesting, plus twosided around or inside "
                        "blendbsdf and mask)", inner.loc or outer.loc)


def bsdf_instance(plugin: Any, textures: Any = None) -> Instance:
    """The instance of a shape's BSDF; a combinator's nested BSDFs are its ``children``
    (``split_leaves`` numbers them)."""
    if plugin.type not in COMBINATORS:
        return leaf_instance(plugin, textures)
    name = plugin.id or plugin.type
    kids = plugin.children
    if plugin.type == "twosided":
        if len(kids) == 1 and kids[0].type in ("blendbsdf", "mask"):
            inst = bsdf_instance(kids[0], textures)  # twosided commutes with them
            if inst.params.get("twosided"):
                raise _nested_error(plugin, kids[0])
            inst.params["twosided"] = True
            return inst
        for k in kids:
            if k.type in COMBINATORS:
                raise _nested_error(plugin, k)
        for k in kids:
            if k.type in TRANSMISSIVE:
                raise CompileError(f"{_where(plugin)}: only BSDFs without transmission can be "
                                   f"nested in twosided, not `{k.type}` (as Mitsuba)",
                                   k.loc or plugin.loc)
        leaves = [leaf_instance(k, textures) for k in kids]
        params = {**MIXTURE, "b": len(leaves) - 1, "twosided": True,
                  "by_side": len(leaves) == 2}
        return Instance("mixture", params, name, leaves)
    unwrapped = [_unwrap_twosided(k) for k in kids]
    flags = {t for _, t in unwrapped}
    for k, _ in unwrapped:
        if k.type in COMBINATORS:
            raise _nested_error(plugin, k)
    if len(flags) > 1:
        raise CompileError(f"{_where(plugin)}: nesting a twosided and a one-sided BSDF is not "
                           "supported by the renderer yet", plugin.loc)
    leaves = [leaf_instance(k, textures) for k, _ in unwrapped]
    if plugin.type == "blendbsdf":
        params = {**MIXTURE, "b": 1, "weight": _float(plugin, "weight")}
    else:
        params = {**MIXTURE, "null": 1.0 - _float(plugin, "opacity")}
    params["twosided"] = flags == {True}
    return Instance("mixture", params, name, leaves)


def _float(plugin: Any, name: str) -> float:
    value = plugin.params[name]
    if not isinstance(value, (int, float)):
        raise CompileError(f"{_where(plugin)}: a texture for `{name}` is not supported by the "
                           "renderer yet", plugin.loc)
    return float(value)


def split_leaves(bsdfs: list[Instance]) -> tuple[list[Instance], list[Instance]]:
    """The top-level instances with their leaf-id parameters numbered across the scene, and
    the scene's leaves (every combinator's nested instances, in order)."""
    top: list[Instance] = []
    leaves: list[Instance] = []
    for inst in bsdfs:
        if not inst.children:
            top.append(inst)
            continue
        params = dict(inst.params)
        for key in LEAF_PARAMS:
            params[key] = len(leaves) + int(params[key])
        top.append(Instance(inst.plugin, params, inst.name))
        leaves += inst.children
    return top, leaves
