"""A scene's BSDFs as ``specialize`` instances: Mitsuba's resolved parameters mapped onto the
``param``s of the stdlib plugins, and the combinators (``twosided``, ``blendbsdf``, ``mask``).

The loader has resolved every Mitsuba parameter (defaults filled in, ``material`` turned into
``eta``/``k``, ``eta = int_ior / ext_ior``; ``alpha_u``/``alpha_v`` set only where the XML
gave them).  Each one is passed to the rdsl plugin's parameter of the same name, after these
conversions: ``distribution`` "ggx"/"beckmann" to 0/1, the XML's ``alpha_u``/``alpha_v`` to
``alpha``/``alpha_v`` (or to ``alpha`` alone where the plugin is isotropic and they agree;
an isotropic ``alpha`` sets ``alpha`` alone, and the plugin's ``alpha_v`` follows it), colors
to RGB tuples and
textures to references (on a ``Float`` parameter, such as a roughness, to the texture's
one-value lookup, Mitsuba's ``eval_1``; the scene schema says which parameters may be
textures).  A parameter the rdsl plugin does not have is an error unless it
holds Mitsuba's default, so nothing is dropped silently.

A user plugin (one with a declaration, runtime/plugins.py) takes the scene's values as its
``param``s say, without these conversions (runtime/render/declared.py); it nests in the
combinators like any BSDF.

A tree of combinators, nested to any depth, is one instance of the rdsl plugin ``mixture``
(``stdlib/bsdf/mixture.rdsl``): the tree is flattened into at most four terms, each a
nested BSDF with its coefficient seen from above and from below (products of the blend
weights and opacities on its path; ``twosided(x, y)`` routes each side to one of them) and
whether it sees directions from below mirrored (a ``twosided`` on its path), plus the
pass-through of ``mask``.  The Int parameters ``a`` .. ``d`` are the ids of the nested BSDFs
among the scene's *leaves* (``SceneSpec.bsdf_leaves``, dispatched by
``stdlib/render/bsdf_leaf.rdsl``).  A blend weight or opacity set by a texture (at most two
per tree) is not folded into the coefficients: it becomes the mixture's ``w0``/``w1``, and
``factors`` says which terms it multiplies, as ``w`` or ``1 - w``.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from dataclasses import dataclass, replace
from functools import cache
from typing import Any

from ...compiler.diagnostics import CompileError
from ...core.color import ColorModel
from ...core.scene_spec import Instance
from ..plugins import INTERNAL, stdlib_names, stdlib_plugin
from ..scene.schema import ANY_TEXTURE, spec_for
from .colors import spectrum_value
from .declared import declared_instance
from .measured import measured_instance

COMBINATORS = ("twosided", "blendbsdf", "mask")  # Mitsuba's, all rdsl's `mixture`
# Mitsuba's, rdsl's `perturbed`: outermost, or alone in a twosided
PERTURBED = ("normalmap", "bumpmap")
LEAF_PARAMS = ("a", "b", "c", "d")  # the mixture's parameters that hold leaf ids
MAX_TERMS = len(LEAF_PARAMS)  # nested BSDFs one combinator tree may hold
TEXTURED_WEIGHTS = 2  # textured blend weights / mask opacities one combinator tree may hold
DISTRIBUTIONS = {"ggx": 0, "beckmann": 1}
TRANSMISSIVE = ("dielectric", "thindielectric", "roughdielectric", "polarizer", "retarder")
# what a polarizing plugin does in an unpolarized render (as Mitsuba 3)
UNPOLARIZED_BEHAVIOUR = {
    "polarizer": "a neutral filter that transmits 50% of the light (times its transmittance)",
    "retarder": "fully transparent: it transmits all light unchanged"}


def scene_bsdfs(desc: Any) -> Iterator[Any]:
    """Every distinct BSDF plugin of the scene's shapes, nested ones included."""
    todo = [shape.bsdf for shape in desc.shapes if getattr(shape, "bsdf", None) is not None]
    seen: set[int] = set()
    while todo:
        plugin = todo.pop(0)
        todo += plugin.children
        if id(plugin) not in seen:
            seen.add(id(plugin))
            yield plugin


def polarization_warnings(desc: Any, model: ColorModel) -> list[str]:
    """Warnings for plugins whose meaning is polarization, in an unpolarized variant."""
    if model.polarized:
        return []
    out = []
    for plugin in scene_bsdfs(desc):
        if plugin.type in UNPOLARIZED_BEHAVIOUR and getattr(plugin, "decl", None) is None:
            out.append(f"{plugin.loc or desc.path}: warning: {_where(plugin)} has no effect on "
                       f"polarization in the unpolarized `{model.name}` variant; it acts as "
                       f"{UNPOLARIZED_BEHAVIOUR[plugin.type]} (as in Mitsuba 3). Render with "
                       "`mono_polarized` or `spectral_polarized` to polarize light.")
    return out


def dispersion_warnings(desc: Any, model: ColorModel) -> list[str]:
    """Warnings for dispersive dielectrics (Cauchy B terms) in a variant without wavelengths."""
    if model.spectral:
        return []
    out = []
    for plugin in scene_bsdfs(desc):
        if getattr(plugin, "decl", None) is None and (plugin.params.get("int_cauchy_b")
                                    or plugin.params.get("ext_cauchy_b")):
            out.append(f"{plugin.loc or desc.path}: warning: {_where(plugin)} is dispersive "
                       f"(Cauchy B term), which only spectral variants render; the `{model.name}` "
                       "variant uses its IOR at 589.3 nm (the sodium D line) for every colour.")
    return out


@cache
def plugin_params(plugin: str, kind: str = "bsdf") -> dict[str, str]:
    """The stdlib plugin's ``param`` names and types, read from its source (cheaply: the
    stdlib is not parsed before the kernel is compiled)."""
    decl = stdlib_plugin(kind, plugin)
    assert decl is not None, plugin
    src = decl.path.read_text()
    return dict(re.findall(r"^\s*param\s+(\w+)\s*:\s*(\w+)", src, re.MULTILINE))


def _where(plugin: Any) -> str:
    return f"bsdf `{plugin.type}`" + (f" (id '{plugin.id}')" if plugin.id else "")


def _value(plugin: Any, name: str, value: Any, textures: Any) -> Any:
    """A parameter value as ``specialize`` takes it."""
    what = f"{plugin.type}.{name}"
    if getattr(value, "category", None) == "texture":
        kind = plugin_params(plugin.type).get(name)
        if textures is None or kind not in ("Texture", "Float"):
            raise CompileError(f"{_where(plugin)}: a texture for `{name}` is not supported by "
                               "the renderer yet", plugin.loc)
        # a Float parameter (a roughness) reads the texture's one-value lookup
        return textures.ref(value, what, "scalar" if kind == "Float" else "colour")
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
    if getattr(plugin, "decl", None) is not None:
        return declared_instance(plugin, textures)
    if plugin.type == "measured_polarized":
        return measured_instance(plugin, textures)
    if stdlib_plugin("bsdf", plugin.type) is None or plugin.type in INTERNAL:
        supported = ", ".join(sorted([*stdlib_names("bsdf"), *COMBINATORS, *PERTURBED]))
        raise CompileError(f"bsdf `{plugin.type}` is not supported by the renderer yet "
                           f"(supported: {supported})", plugin.loc)
    ours = plugin_params(plugin.type)
    p = dict(plugin.params)
    p.pop("material", None)  # resolved into eta / k
    # sampling only: the image converges to the same either way (rdsl always samples the
    # visible normals)
    p.pop("sample_visible", None)
    if "int_ior" in p:
        p.pop("eta", None)   # derived: int_ior / ext_ior
    if p.get("distribution") is not None:
        p["distribution"] = DISTRIBUTIONS[p["distribution"]]
    if p.get("alpha_u") is None:  # isotropic: `alpha` (the plugin's alpha_v follows it)
        p.pop("alpha_u", None)
        p.pop("alpha_v", None)
    else:
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


def perturbed_instance(plugin: Any, textures: Any, twosided: bool = False,
                       prefix: str | None = None) -> Instance:
    """A ``normalmap`` or ``bumpmap`` (in a ``twosided``: the frame is mirrored for light from
    below): the internal plugin ``perturbed`` (stdlib/bsdf/perturbed.rdsl), the nested BSDF's
    mixture parameters and leaves plus the texture that perturbs the shading normal
    (``prefix``: the leaves' names start with it, see :func:`bsdf_instance`)."""
    nested = plugin.children[0]
    if twosided and nested.type in TRANSMISSIVE:
        raise CompileError(f"{_where(nested)}: only BSDFs without transmission can be nested "
                           f"in twosided, not `{nested.type}` (as Mitsuba)", nested.loc)
    inner_name = f"{prefix or plugin.id or plugin.type}.nested_bsdf"  # Mitsuba's key
    if nested.type in COMBINATORS:
        inner = bsdf_instance(nested, textures, inner_name)
        params, leaves = dict(inner.params), inner.children
    else:
        params = mixture_params([(0, 1.0, 1.0, False)])
        leaves = [replace(leaf_instance(nested, textures), name=inner_name)]
    bump = plugin.type == "bumpmap"
    name = ANY_TEXTURE if bump else "normalmap"
    tex = plugin.params.get(name)
    if getattr(tex, "category", None) != "texture" or getattr(tex, "type", None) != "bitmap":
        got = (f"a `{tex.type}` texture" if getattr(tex, "category", None) == "texture"
               else "a constant")
        raise CompileError(f"{_where(plugin)}: `{name}` must be a bitmap texture (the renderer "
                           f"reads its {'gradient' if bump else 'RGB normals'}), got {got}",
                           getattr(tex, "loc", None) or plugin.loc)
    if textures is None:
        raise CompileError(f"{_where(plugin)}: textures are not available here", plugin.loc)
    ref = textures.ref(tex, f"{plugin.type}.{name}", "scalar")
    params.update(bump=bump, tex=ref.index, scale=float(plugin.params.get("scale", 1.0)),
                  flags=int(bool(plugin.params["flip_invalid_normals"]))
                  | 2 * int(bool(plugin.params["use_shadowing_function"])) | 8 * int(twosided))
    return Instance("perturbed", params, plugin.id or plugin.type, leaves)


def bsdf_instance(plugin: Any, textures: Any = None, prefix: str | None = None) -> Instance:
    """The instance of a shape's BSDF; a combinator's nested BSDFs are its ``children``
    (``split_leaves`` numbers them), named as Mitsuba's ``mi.traverse`` names them: the
    outermost BSDF's id (or ``prefix``) and the path of keys down to them (``brdf_0``,
    ``brdf_1`` in a twosided, ``bsdf_0``, ``bsdf_1`` in a blendbsdf, ``nested_bsdf`` in a
    mask, a normalmap and a bumpmap), whatever ids they have themselves."""
    top = prefix or plugin.id or plugin.type
    if plugin.type in PERTURBED:
        return perturbed_instance(plugin, textures, prefix=top)
    if (plugin.type == "twosided" and len(plugin.children) == 1
            and plugin.children[0].type in PERTURBED):
        return perturbed_instance(plugin.children[0], textures, twosided=True,
                                  prefix=f"{top}.brdf_0")
    if plugin.type not in COMBINATORS:
        leaf = leaf_instance(plugin, textures)
        return replace(leaf, name=top) if prefix else leaf
    tree = _Tree(textures)
    tree.flatten(plugin, 1.0, 1.0, (), False, False)
    terms = [t for t in tree.terms if t.above > 0.0 or t.below > 0.0]
    if len(terms) > MAX_TERMS:
        raise CompileError(f"{_where(plugin)}: combinators that nest {len(terms)} BSDFs are not "
                           f"supported by the renderer yet (at most {MAX_TERMS})", plugin.loc)
    if not terms:  # fully transparent: a mixture whose one term has no share
        terms = [_Term(_first_leaf(plugin), 0.0, 0.0, (), False)]
    null = [t for t in tree.null if t.above > 0.0 or t.below > 0.0]
    if len({t.factors for t in null}) > 1:
        raise CompileError(f"{_where(plugin)}: masks whose opacities come from different "
                           "textures on different paths of one combinator tree are not "
                           "supported by the renderer yet", plugin.loc)
    # the pass-through's factors are term MAX_TERMS's (mixture_factor(4, ...)), whatever
    # the number of terms
    factors = ([t.factors for t in terms] + [()] * (MAX_TERMS - len(terms))
               + [null[0].factors if null else ()])
    params = mixture_params([(k, t.above, t.below, t.mirror) for k, t in enumerate(terms)],
                            sum(t.above for t in null), sum(t.below for t in null))
    params["factors"] = sum(mode << (4 * i + 2 * j) for i, fs in enumerate(factors)
                            for j, mode in fs)
    params["w0"], params["w1"] = (tree.weights + [1.0, 1.0])[:TEXTURED_WEIGHTS]
    leaves = []
    for t in terms:  # each leaf's textures without ids named after the leaf's path
        name = ".".join((top, *t.path))
        with textures.owned_by(name) if textures is not None else contextlib.nullcontext():
            leaves.append(replace(leaf_instance(t.leaf, textures), name=name))
    return Instance("mixture", params, plugin.id or plugin.type, leaves)


def mixture_params(terms: list[tuple[int, float, float, bool]], null_above: float = 0.0,
                   null_below: float = 0.0) -> dict[str, Any]:
    """The ``mixture`` plugin's parameters for (leaf id, coefficient from above, from below,
    mirrored from below) terms and the pass-through's coefficients (no textured weights)."""
    assert len(terms) <= MAX_TERMS
    full = list(terms) + [(terms[0][0] if terms else 0, 0.0, 0.0, False)] * (MAX_TERMS -
                                                                             len(terms))
    params: dict[str, Any] = dict(zip(LEAF_PARAMS, (t[0] for t in full)))
    params["above"] = tuple(float(t[1]) for t in full)
    params["below"] = tuple(float(t[2]) for t in full)
    params["mirror"] = sum(1 << i for i, t in enumerate(full) if t[3])
    params["null_above"], params["null_below"] = float(null_above), float(null_below)
    params["factors"], params["w0"], params["w1"] = 0, 1.0, 1.0
    return params


@dataclass
class _Term:
    """A nested BSDF of a combinator tree (or, in ``_Tree.null``, a share of the
    pass-through) with its constant coefficients seen from above and from below, its
    textured factors ((weight slot, 1: w or 2: 1 - w) pairs), and whether it sees directions
    from below mirrored (it is inside a twosided)."""

    leaf: Any
    above: float
    below: float
    factors: tuple[tuple[int, int], ...]
    mirror: bool
    path: tuple[str, ...] = ()  # Mitsuba's keys from the tree's root (bsdf_instance)


class _Tree:
    """The terms of a combinator tree, its pass-through shares and its textured weights."""

    def __init__(self, textures: Any) -> None:
        self.textures = textures
        self.terms: list[_Term] = []
        self.null: list[_Term] = []
        self.weights: list[Any] = []  # TextureRefs of the textured weights, by slot

    def weight(self, plugin: Any, name: str) -> tuple[float, float, int | None]:
        """A blend weight or opacity w: the constant factors w and 1 - w and None, or 1, 1
        and the weight's slot for a texture (then the factors are textured)."""
        value = plugin.params[name]
        if isinstance(value, (int, float)):
            w = min(max(float(value), 0.0), 1.0)
            return w, 1.0 - w, None
        if getattr(value, "category", None) != "texture" or self.textures is None:
            raise CompileError(f"{_where(plugin)}: cannot use {value!r} as `{name}`",
                               plugin.loc)
        if len(self.weights) == TEXTURED_WEIGHTS:
            raise CompileError(f"{_where(plugin)}: a combinator tree may take at most "
                               f"{TEXTURED_WEIGHTS} weights or opacities from textures in the "
                               "renderer", plugin.loc)
        self.weights.append(self.textures.ref(value, f"{plugin.type}.{name}", "scalar"))
        return 1.0, 1.0, len(self.weights) - 1

    def flatten(self, plugin: Any, above: float, below: float,
                factors: tuple[tuple[int, int], ...], mirror: bool, in_twosided: bool,
                path: tuple[str, ...] = ()) -> None:
        """Add the terms of ``plugin``'s subtree, reached with coefficients ``above`` and
        ``below`` and textured ``factors``; ``mirror``: the path from below has passed a
        twosided, which turned the directions over (after that the subtree is seen from its
        front side only)."""
        if plugin.type in PERTURBED:
            raise CompileError(f"{_where(plugin)}: a {plugin.type} nested in a combinator "
                               "(twosided, blendbsdf, mask) is not supported by the renderer "
                               f"yet; make the {plugin.type} the outermost BSDF or the only "
                               "one in a twosided", plugin.loc)
        if plugin.type not in COMBINATORS:
            if in_twosided and plugin.type in TRANSMISSIVE:
                raise CompileError(f"{_where(plugin)}: only BSDFs without transmission can be "
                                   f"nested in twosided, not `{plugin.type}` (as Mitsuba)",
                                   plugin.loc)
            self.terms.append(_Term(plugin, above, below, factors, mirror, path))
            return
        kids = plugin.children
        if plugin.type in ("blendbsdf", "mask"):
            w, rest, slot = self.weight(plugin, "weight" if plugin.type == "blendbsdf"
                                        else "opacity")
            on = factors + ((slot, 1),) if slot is not None else factors
            off = factors + ((slot, 2),) if slot is not None else factors
            if plugin.type == "blendbsdf":
                self.flatten(kids[0], above * rest, below * rest, off, mirror, in_twosided,
                             (*path, "bsdf_0"))
                self.flatten(kids[1], above * w, below * w, on, mirror, in_twosided,
                             (*path, "bsdf_1"))
            else:
                self.null.append(_Term(None, above * rest, below * rest, off, mirror))
                self.flatten(kids[0], above * w, below * w, on, mirror, in_twosided,
                             (*path, "nested_bsdf"))
        elif len(kids) == 1 or mirror:
            # twosided(x): from below, x sees mirrored directions; a twosided(x, y) already
            # turned to its front side sees x only
            self.flatten(kids[0], above, below, factors, True, True, (*path, "brdf_0"))
        else:  # twosided(x, y): x from above, y from below (mirrored)
            self.flatten(kids[0], above, 0.0, factors, True, True, (*path, "brdf_0"))
            self.flatten(kids[1], 0.0, below, factors, True, True, (*path, "brdf_1"))


def _first_leaf(plugin: Any) -> Any:
    while plugin.type in COMBINATORS:
        plugin = plugin.children[0]
    return plugin


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
