"""From the XML object tree to a :class:`SceneDescription` the renderer can use.

Each object is checked against :mod:`.schema`: an unknown plugin, an unknown parameter, a
value of the wrong kind or a missing required parameter is a :class:`SceneError` naming the
file, the line, the plugin and what it accepts.  Parameters not given take Mitsuba 3's
defaults, and derived values are resolved here (conductor ``material`` to ``eta``/``k``,
the camera's field of view to ``fov_x``, the film's crop window; ``alpha_u``/``alpha_v``
are checked: both or neither, and not with ``alpha``).  Shapes carry their triangle mesh
in world space.  Nothing is half-loaded: the first error stops the load.

A ``bsdf``, ``texture`` or ``emitter`` type is resolved through the scene's plugin registry
(runtime/plugins.py): a user plugin is checked against its own ``param`` declarations
(:func:`rdsl.runtime.plugins.declared_spec`), and its errors name the declaration too.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from ..plugins import KINDS as PLUGIN_KINDS
from ..plugins import PluginDecl, PluginRegistry, scene_spec, stdlib_names
from . import transform as xf
from .analytic import Analytic
from .curves import Curves
from .errors import scene_error
from .finish import Finishers
from .meshes import Mesh
from .nodes import param_str as _param_str
from .samplers import attach_samplers
from .schema import (
    KIND_ACCEPTS,
    KIND_NAMES,
    REQUIRED,
    SCENE_CHILDREN,
    Param,
    PluginSpec,
    plugin_types,
)
from .sensors import top_level_sensor
from .shape_build import ShapeFinisher, drawn_shapes, shape_points
from .spectra import Color, as_reflectance, flat_emission, lookup_ior
from .xml import Child, ObjectNode, Prop, SceneTree, read_scene


@dataclass
class Plugin:
    """An instantiated plugin: its type and every parameter, resolved, defaults filled in."""

    category: str
    type: str
    params: dict[str, Any]
    id: str | None = None
    loc: Loc | None = None
    children: list[Plugin] = field(default_factory=list)  # nested BSDFs / integrators
    # a plugin whose params are its declaration's (a user plugin), not Mitsuba's schema
    decl: PluginDecl | None = None

    def __getitem__(self, name: str) -> Any:
        return self.params[name]


@dataclass
class Sensor(Plugin):
    """A camera, with its film (and the film's ``rfilter`` child) and sampler."""

    film: Plugin | None = None
    sampler: Plugin | None = None
    shape: Plugin | None = None  # the shape an irradiancemeter is nested in


@dataclass
class Shape(Plugin):
    """A shape with its world-space triangle mesh, its BSDF and its area emitter if any."""

    mesh: Mesh | None = None
    # a sphere or disk, intersected and shaded exactly (None: render the mesh)
    analytic: Analytic | None = None
    curves: Curves | None = None  # a linearcurve or bsplinecurve (then mesh is None)
    bsdf: Plugin | None = None
    emitter: Plugin | None = None
    sensor: Sensor | None = None  # an irradiancemeter nested in it


@dataclass
class SceneDescription:
    """Everything a scene file describes, ready for the renderer."""

    path: Path
    integrator: Plugin
    sensors: list[Sensor]
    shapes: list[Shape]
    emitters: list[Plugin]          # area emitters (also on their shape) and the others
    ids: dict[str, Plugin]
    params: dict[str, str]          # the $parameters after <default> and -D
    # name -> declaration of the plugins the scene resolved (the kernel imports their files)
    plugins: dict[str, PluginDecl] = field(default_factory=dict)

    @property
    def sensor(self) -> Sensor:
        return self.sensors[0]

    def integer_loc(self, value: int) -> Loc:
        """The line of the first plugin with an integer parameter equal to ``value`` (the
        scene's first line if none has one)."""
        stack: list[Any] = [self.integrator, *self.sensors, *self.shapes, *self.emitters,
                            *self.ids.values()]
        seen: set[int] = set()
        while stack:
            p = stack.pop(0)
            if id(p) in seen:
                continue
            seen.add(id(p))
            if p.loc is not None and any(type(v) is int and v == value
                                         for v in p.params.values()):
                return p.loc
            stack.extend(v for f in vars(p).values()
                         for v in (f if isinstance(f, list) else [f]) if isinstance(v, Plugin))
        return Loc(str(self.path), 1, 1)


def load_scene_description(path: str | Path, *, plugins: Any = (),
                           **defaults: Any) -> SceneDescription:
    """Load a Mitsuba 3 scene; ``defaults`` override ``<default>`` values (``-D name=value``);
    ``plugins``: folders or files searched for plugins after the scene's folder."""
    tree = read_scene(path, {k: str(v) for k, v in defaults.items()})
    if tree.unused_defines:
        warnings.warn(f"{tree.path}: parameters never used by the scene: "
                      f"{', '.join(tree.unused_defines)}", stacklevel=2)
    return _Builder(tree, PluginRegistry.for_scene(tree.path, plugins)).build()


class _Builder(ShapeFinisher, Finishers):
    """Instantiates the XML tree's objects; ``finish_<category>`` (shape_build.py, finish.py)
    checks each one and resolves its derived values."""

    def __init__(self, tree: SceneTree, registry: PluginRegistry) -> None:
        self.tree = tree
        self.registry = registry
        self.specs: dict[tuple[str, str], PluginSpec | None] = {}
        self.plugins: dict[str, PluginDecl] = {}
        # keyed by id(); the node is kept so that a freed temporary's id is never reused
        self.done: dict[int, tuple[ObjectNode, Plugin]] = {}
        self.ids: dict[str, Plugin] = {}

    # -- the scene ---------------------------------------------------------------------
    def build(self) -> SceneDescription:
        root = self.tree.root
        integrators, sensors, shapes, emitters, samplers = [], [], [], [], []
        for ch in root.children:
            cat = ch.node.category
            if cat == "sampler":  # as Mitsuba's docs scenes: for sensors without their own
                samplers.append(self.instantiate(ch.node))
                continue
            if cat not in SCENE_CHILDREN:
                where = {"rfilter": "<film>", "volume": '<texture type="volume">'}.get(
                    cat, "<sensor>")
                raise scene_error(f"<{cat}> cannot appear directly inside <scene>; nest it "
                                  f"inside {where}", ch.loc)
            obj = self.instantiate(ch.node)
            if cat == "integrator":
                integrators.append(obj)
            elif cat == "sensor":
                sensors.append(top_level_sensor(obj, ch.loc))
            elif cat == "shape":
                for shape in drawn_shapes(obj):
                    shapes.append(shape)
                    sensors += [shape.sensor] if shape.sensor is not None else []
                    if shape.emitter is not None:
                        emitters.append(shape.emitter)
            elif cat == "emitter":
                if obj.type == "area" or obj.decl is not None:
                    raise scene_error(f"an '{obj.type}' emitter must be nested inside a "
                                      "<shape> (plugin emitters are area lights)", ch.loc)
                emitters.append(obj)
        if len(integrators) > 1:
            raise scene_error("the scene declares more than one <integrator>",
                              integrators[1].loc)
        integrator = integrators[0] if integrators else self.default("integrator", "path")
        if not sensors:
            sensors.append(self.default_sensor(shapes))
        attach_samplers(sensors, samplers, lambda: self.default("sampler", "independent"))
        return SceneDescription(self.tree.path, integrator, sensors, shapes, emitters,
                                self.ids, dict(self.tree.params), self.plugins)

    def default(self, category: str, ptype: str, **params: Any) -> Plugin:
        node = ObjectNode(category, ptype, None, Loc(str(self.tree.path), 0, 0),
                          self.tree.path.parent)
        for k, v in params.items():
            node.props[k] = Prop(_prop_kind(v), v, node.loc)
        return self.instantiate(node)

    def default_sensor(self, shapes: list[Shape]) -> Sensor:
        # Mitsuba frames the scene's bounding box with a 45 degree camera.
        pts = np.vstack([np.zeros((0, 3)), *(shape_points(s) for s in shapes)])
        if len(pts):
            lo, hi = pts.min(axis=0), pts.max(axis=0)
        else:
            lo, hi = np.zeros(3), np.zeros(3)
        center, ext = (lo + hi) / 2, hi - lo
        dist = max(float(ext.max()), 1e-3) / (2 * math.tan(math.radians(22.5)))
        m = xf.translate([center[0], center[1], lo[2] - dist])
        return self.default("sensor", "perspective", fov=45.0, to_world=m,
                            far_clip=float(ext.max()) * 5 + dist, near_clip=dist / 100,
                            focus_distance=dist + float(ext[2]) / 2)

    # -- one object --------------------------------------------------------------------
    def instantiate(self, node: ObjectNode) -> Plugin:
        key = id(node)
        if key in self.done:
            return self.done[key][1]
        spec = self.spec(node)
        params, objects = self.collect(node, spec)
        cls = {"shape": Shape, "sensor": Sensor}.get(node.category, Plugin)
        obj = cls(node.category, node.type, params, node.id, node.loc, decl=spec.decl)
        for cat, items in objects.items():
            lo, hi = spec.children[cat]
            if not lo <= len(items) <= hi:
                want = str(lo) if lo == hi else f"{lo} to {hi}"
                raise scene_error(f"{self.what(node)} takes {want} nested <{cat}>, got "
                                  f"{len(items)}", items[-1][1].loc if items else node.loc)
        getattr(self, f"finish_{node.category}")(obj, node, objects)
        self.done[key] = (node, obj)
        if node.id is not None:
            self.ids[node.id] = obj
        return obj

    def spec(self, node: ObjectNode) -> PluginSpec:
        """The schema of the node's plugin, resolved once per scene (user plugins first)."""
        key = (node.category, node.type)
        if key not in self.specs:
            self.specs[key] = scene_spec(self.registry, *key)
        spec = self.specs[key]
        if spec is None:
            names = dict.fromkeys([*plugin_types(node.category), *stdlib_names(node.category),
                                   *self.registry.user_names(node.category)])
            hint = (f" (no .rdsl file next to the scene or in the plugin folders declares "
                    f"`{node.category} {node.type}`)" if node.category in PLUGIN_KINDS else "")
            other = next(((k, d) for k in PLUGIN_KINDS if k != node.category
                          for d in self.registry.candidates(k, node.type)[:1]), None)
            if other is not None and node.category in PLUGIN_KINDS:
                k, d = other
                hint = (f"; `{node.type}` is declared as {_article(k)} {k} plugin at "
                        f"{d.where}, not as {_article(node.category)} {node.category} "
                        f"plugin: {_article(node.category)} <{node.category}> needs "
                        f"`{node.category} {node.type} {{`")
            raise scene_error(f"unknown {node.category} plugin '{node.type}'; accepted: "
                              f"{', '.join(names)}{hint}", node.loc)
        decl = spec.decl
        if decl is not None:
            other = self.plugins.setdefault(decl.name, decl)
            if other is not decl:
                raise scene_error(f"two plugins named `{decl.name}` in one scene "
                                  f"({other.where}, {decl.where}); rename one", node.loc)
        return spec

    def what(self, node: ObjectNode) -> str:
        spec = self.specs.get((node.category, node.type))
        decl = spec.decl if spec is not None else None
        where = f" (declared at {decl.where})" if decl is not None else ""
        return f"{node.category} '{node.type}'{where}"

    def collect(self, node: ObjectNode, spec: PluginSpec
                ) -> tuple[dict[str, Any], dict[str, list[tuple[Plugin, Child]]]]:
        accepted = ", ".join(spec.params) or "no parameters"
        params: dict[str, Any] = {}
        objects: dict[str, list[tuple[Plugin, Child]]] = {c: [] for c in spec.children}
        for name, prop in node.props.items():
            if name not in spec.params:
                raise scene_error(f"unknown parameter '{name}' of {self.what(node)}; "
                                  f"accepted: {accepted}", prop.loc)
            if spec.decl is not None and prop.kind == "string":  # rdsl has no strings
                raise scene_error(f"parameter '{name}' of {self.what(node)} is a string, which "
                                  f"no rdsl param takes{_declared(name, spec.params[name])}",
                                  prop.loc)
            params[name] = self.convert(node, name, spec.params[name], prop.kind, prop.value,
                                        prop.loc)
        for ch in node.children:
            cat = ch.node.category
            ref = (f" (a <ref> to {cat} '{ch.node.id}', declared at {ch.node.loc})"
                   if ch.is_ref else "")
            if cat == "texture":
                name = spec.texture_param(ch.name)
                if name is None:
                    raise scene_error(f"a <texture>{ref} nested in {self.what(node)} needs a "
                                      "name=\"...\" attribute naming the parameter it sets "
                                      f"(accepted: {accepted})", ch.loc)
                if name not in spec.params:
                    raise scene_error(f"unknown parameter '{name}' of {self.what(node)}{ref}"
                                      f"; accepted: {accepted}", ch.loc)
                params[name] = self.convert(node, name, spec.params[name], "texture",
                                            ch.node, ch.loc)
                continue
            if cat not in spec.children:
                if ch.name in spec.params:
                    raise scene_error(f"parameter '{ch.name}' of {self.what(node)} expects "
                                      f"{KIND_NAMES[spec.params[ch.name].kind]}, got a "
                                      f"<{cat}>{ref}", ch.loc)
                acc = ", ".join(f"<{c}>" for c in spec.children) or "no nested objects"
                raise scene_error(f"{self.what(node)} does not accept a nested <{cat}>{ref}; "
                                  f"it accepts {acc}", ch.loc)
            objects[cat].append((self.instantiate(ch.node), ch))
        for name, p in spec.params.items():
            if name in params:
                continue
            if p.default is REQUIRED:
                raise scene_error(f"{self.what(node)} is missing the required parameter "
                                  f"'{name}' ({KIND_NAMES[p.kind]}){_declared(name, p)}",
                                  node.loc)
            if p.default is not None:
                params[name] = self.convert(node, name, p, _prop_kind(p.default), p.default,
                                            node.loc)
            else:
                params[name] = None
        return params, objects

    def convert(self, node: ObjectNode, name: str, p: Param, kind: str, value: Any,
                loc: Loc) -> Any:
        if kind not in KIND_ACCEPTS[p.kind]:
            got = f"<{kind}>" if kind != "texture" else "a <texture>"
            if kind == "texture" and not isinstance(value, ObjectNode):
                got = "a texture"
            raise scene_error(f"parameter '{name}' of {self.what(node)} expects "
                              f"{KIND_NAMES[p.kind]}, got {got}{_declared(name, p)}", loc)
        if kind == "texture":
            return self.instantiate(value)
        if p.rdsl_type in ("UInt", "UInt64") and value < 0:
            raise scene_error(f"parameter '{name}' of {self.what(node)} is unsigned, so it "
                              f"cannot be {value}{_declared(name, p)}", loc)
        if p.kind == "float":
            return float(value)
        if p.kind == "vec3":
            return np.asarray(value.rgb if kind == "rgb" else value, dtype=np.float64)
        if p.kind in ("ftex", "fconst"):
            if kind in ("float", "integer"):
                return float(value)
            return _constant(value, f"parameter '{name}' of {self.what(node)}", kind,
                             _declared(name, p), loc)
        if p.kind in ("color", "spectrum"):
            if kind in ("float", "integer"):
                return Color.gray(value)
            if min(value.rgb) < 0:  # a single negative value is kept for angles (fconst)
                raise scene_error(f"<{kind} name=\"{name}\">: a color must be non-negative, "
                                  f"got {value.rgb[0]:g}", loc)
            if (kind == "rgb" and (node.category, node.type) == ("texture", "checkerboard")
                    and max(value.rgb) > 1):
                # Mitsuba's checkerboard takes an <rgb> as a reflectance (srgb, bounded)
                raise scene_error(f"<rgb name=\"{name}\"> of {self.what(node)}: a "
                                  "checkerboard's rgb colour is a reflectance, in [0, 1], got "
                                  f"{', '.join(f'{v:g}' for v in value.rgb)} (give a "
                                  "<spectrum> or a <float> for a brighter one)", loc)
            if node.category == "emitter":  # a constant <spectrum>: flat, not grey
                return flat_emission(value) if kind == "spectrum" else value
            return as_reflectance(value, name)  # pairs seen under D65, as Mitsuba's
        if p.kind == "ior":
            ior = lookup_ior(value, loc) if kind == "string" else float(value)
            if ior < 0:
                raise scene_error(f"'{name}' must be a positive index of refraction", loc)
            return ior
        if p.kind in ("point", "vector"):
            return np.asarray(value, dtype=np.float64)
        if p.kind == "string" and p.choices and value not in p.choices:
            raise scene_error(f"parameter '{name}' of {self.what(node)} is '{value}'; "
                              f"accepted: {', '.join(p.choices)}", loc)
        return value

    def file(self, node: ObjectNode, name: str, what: str) -> Path:
        loc = node.props[name].loc if name in node.props else node.loc
        return self.tree.resolve_file(_param_str(node, name), node.base_dir,
                                      f"{self.what(node)}: {what}", loc)


def _article(word: str) -> str:
    return "an" if word[0] in "aeiou" else "a"


def _declared(name: str, p: Param) -> str:
    """Where a user plugin's param is declared, for messages ("" for Mitsuba's)."""
    return f" (declared `param {name}: {p.rdsl_type}` at {p.decl})" if p.decl else ""


def _constant(value: Color, what: str, kind: str, declared: str, loc: Loc) -> float:
    """A ``<spectrum>`` or ``<rgb>`` given for a scalar: the constant it holds.  Mitsuba 3 would
    take a varying one as a texture evaluated per wavelength; rdsl's scalar params cannot."""
    vals = value.values if value.wavelengths is not None else value.rgb
    if max(vals) != min(vals):
        raise scene_error(f"{what} takes one number (or a texture where Mitsuba does), but the "
                          f"<{kind}> given varies ({', '.join(f'{v:g}' for v in vals)}); give "
                          f"one value{declared}", loc)
    return float(vals[0])



def _prop_kind(v: Any) -> str:
    if isinstance(v, bool):
        return "boolean"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "float"
    if isinstance(v, str):
        return "string"
    if isinstance(v, np.ndarray):
        return "transform" if v.shape == (4, 4) else "point"
    if isinstance(v, Color):
        return "rgb"
    raise TypeError(type(v))
