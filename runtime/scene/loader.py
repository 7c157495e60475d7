"""From the XML object tree to a :class:`SceneDescription` the renderer can use.

Each object is checked against :mod:`.schema`: an unknown plugin, an unknown parameter, a
value of the wrong kind or a missing required parameter is a :class:`SceneError` naming the
file, the line, the plugin and what it accepts.  Parameters not given take Mitsuba 3's
defaults, and derived values are resolved here (conductor ``material`` to ``eta``/``k``,
``alpha`` to ``alpha_u``/``alpha_v``, the camera's field of view to ``fov_x``, the film's
crop window).  Shapes carry their triangle mesh in world space.  Nothing is half-loaded: the
first error stops the load.

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
from . import meshes
from . import transform as xf
from .analytic import Analytic
from .cylinder import cylinder_frame, cylinder_mesh
from .errors import scene_error
from .meshes import Mesh, MeshError
from .principled import resolve_principled
from .reads import memoized
from .samplers import attach_samplers, finish_sampler
from .schema import (
    AOV_TYPES,
    BITMAP_FORMATS,
    KIND_ACCEPTS,
    KIND_NAMES,
    REQUIRED,
    SCENE_CHILDREN,
    Param,
    PluginSpec,
    plugin_types,
)
from .sensors import METERS, attach_meter, finish_sensor, top_level_sensor
from .spectra import Color, as_reflectance, conductor_ior, flat_emission, lookup_ior
from .xml import Child, ObjectNode, Prop, SceneTree, read_scene

# the largest Cauchy B term accepted (um^2): glasses are below 0.02, so a larger value is a
# unit mistake (nm^2) rather than a material
MAX_CAUCHY_B = 1.0


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


def load_scene_description(path: str | Path, *, plugins: Any = (),
                           **defaults: Any) -> SceneDescription:
    """Load a Mitsuba 3 scene; ``defaults`` override ``<default>`` values (``-D name=value``);
    ``plugins``: folders or files searched for plugins after the scene's folder."""
    tree = read_scene(path, {k: str(v) for k, v in defaults.items()})
    if tree.unused_defines:
        warnings.warn(f"{tree.path}: parameters never used by the scene: "
                      f"{', '.join(tree.unused_defines)}", stacklevel=2)
    return _Builder(tree, PluginRegistry.for_scene(tree.path, plugins)).build()


class _Builder:
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
                where = "<film>" if cat == "rfilter" else "<sensor>"
                raise scene_error(f"<{cat}> cannot appear directly inside <scene>; nest it "
                                  f"inside {where}", ch.loc)
            obj = self.instantiate(ch.node)
            if cat == "integrator":
                integrators.append(obj)
            elif cat == "sensor":
                sensors.append(top_level_sensor(obj, ch.loc))
            elif cat == "shape":
                shapes.append(obj)
                sensors += [obj.sensor] if obj.sensor is not None else []
                if obj.emitter is not None:
                    emitters.append(obj.emitter)
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
        if shapes:
            pts = np.vstack([s.mesh.vertices for s in shapes]).astype(np.float64)
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

    # -- per-category checks and derived values ----------------------------------------
    def finish_shape(self, obj: Shape, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        m = p["to_world"] if p["to_world"] is not None else xf.identity()
        if xf.singular(m):
            raise scene_error(f"{self.what(node)}: 'to_world' is singular or not finite",
                              _loc(node, "to_world"))
        if obj.type == "sphere":
            if p["radius"] <= 0:
                raise scene_error("sphere: 'radius' must be positive", _loc(node, "radius"))
            center = p["center"] if p["center"] is not None else np.zeros(3)
            p["center"] = center
            m = m @ xf.translate(center) @ xf.scale(p["radius"])
            mesh = meshes.sphere()
        elif obj.type in ("rectangle", "cube", "disk"):
            mesh = getattr(meshes, obj.type)()
        elif obj.type == "cylinder":
            m, mesh = m @ cylinder_frame(p, lambda k: _loc(node, k)), cylinder_mesh()
        else:
            path = self.file(node, "filename", "mesh")
            try:
                mesh = memoized(path, (obj.type, p.get("flip_tex_coords"),
                                       p.get("shape_index")),
                                lambda: meshes.read_mesh(obj.type, path, obj.params))
            except MeshError as e:
                raise scene_error(f"{self.what(node)}: cannot load mesh file '{p['filename']}':"
                                  f" {e}", _loc(node, "filename")) from None
            except OSError as e:
                raise scene_error(f"{self.what(node)}: cannot read mesh file "
                                  f"'{p['filename']}': {e.strerror}",
                                  _loc(node, "filename")) from None
            p["filename"] = str(path)
        if obj.type in ("sphere", "disk") and not p["triangulate"]:
            obj.analytic = Analytic(obj.type, m, bool(p["flip_normals"]))
            problem = obj.analytic.uniform_scale_problem()
            if problem:  # Mitsuba warns and keeps a sphere of radius |to_world (1, 0, 0)|
                loc = _loc(node, "to_world")
                warnings.warn(f"{loc.file}:{loc.line}: sphere: {problem} (the sphere keeps "
                              f"radius {obj.analytic.radius:g}); set 'triangulate' to render "
                              "the transformed mesh instead", stacklevel=2)
        face_normals = bool(p.get("face_normals") or mesh.face_normals)
        p["to_world"] = m
        try:
            obj.mesh = meshes.to_world(mesh, m, p["flip_normals"], face_normals)
        except MeshError as e:
            raise scene_error(f"{self.what(node)}: {e}", _loc(node, "to_world")) from None
        bsdfs, ems = objects["bsdf"], objects["emitter"]
        # Mitsuba's default (shape.cpp): diffuse, black on an emitter's shape
        obj.bsdf = bsdfs[0][0] if bsdfs else self.default(
            "bsdf", "diffuse", **({"reflectance": 0.0} if ems else {}))
        if ems:
            em, ch = ems[0]
            if em.type != "area" and em.decl is None:
                raise scene_error(f"only an 'area' emitter can be attached to a shape, not "
                                  f"'{em.type}'", ch.loc)
            obj.emitter = em
        if objects.get("sensor"):
            attach_meter(obj, *objects["sensor"][0])

    def finish_bsdf(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = [b for b, _ in objects.get("bsdf", [])]
        if obj.decl is not None:  # a user plugin: its params are its own, not Mitsuba's
            return
        if obj.type == "principled":
            resolve_principled(p, lambda k: _loc(node, k) is not node.loc, self.what(node),
                               lambda k: _loc(node, k))
        if "material" in p:
            given = [k for k in ("eta", "k") if p[k] is not None]
            if given and "material" in node.props:
                raise scene_error(f"{self.what(node)}: give either 'material' or 'eta'/'k', "
                                  "not both", _loc(node, "material"))
            if given:
                p["eta"] = p["eta"] if p["eta"] is not None else Color.gray(0.0)
                p["k"] = p["k"] if p["k"] is not None else Color.gray(1.0)
            else:
                p["eta"], p["k"] = conductor_ior(p["material"], _loc(node, "material"))
        if "alpha_u" in p:
            has_u, has_v = p["alpha_u"] is not None, p["alpha_v"] is not None
            if has_u != has_v:
                raise scene_error(f"{self.what(node)}: give both 'alpha_u' and 'alpha_v'",
                                  _loc(node, "alpha_u" if has_u else "alpha_v"))
            if has_u and "alpha" in node.props:
                raise scene_error(f"{self.what(node)}: give either 'alpha' or "
                                  "'alpha_u'/'alpha_v', not both", _loc(node, "alpha"))
            if not has_u:
                p["alpha_u"] = p["alpha_v"] = p["alpha"]
        if "int_ior" in p:
            p["eta"] = p["int_ior"] / p["ext_ior"] if p["ext_ior"] > 0 else 0.0
        for side in ("int", "ext"):
            b = p.get(f"{side}_cauchy_b")
            if b is not None and not 0.0 <= b <= MAX_CAUCHY_B:
                raise scene_error(
                    f"{self.what(node)}: '{side}_cauchy_b' is {b:g}; Cauchy's B term is in "
                    f"um^2 and must lie in [0, {MAX_CAUCHY_B:g}] (BK7: 0.00420, dense flint "
                    "glass: ~0.014; a value in nm^2 is 10^6 times too large)",
                    _loc(node, f"{side}_cauchy_b"))

    def finish_texture(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        if p.get("to_uv") is None and (obj.decl is None or "to_uv" in p):
            p["to_uv"] = xf.identity()
        if obj.type == "bitmap" and obj.decl is None:
            path = self.file(node, "filename", "texture")
            if path.suffix.lower() not in BITMAP_FORMATS:
                raise scene_error(f"bitmap: image format '{path.suffix}' of '{p['filename']}' "
                                  f"is not supported; accepted: {', '.join(BITMAP_FORMATS)}",
                                  _loc(node, "filename"))
            p["filename"] = str(path)

    def finish_emitter(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        if obj.decl is not None:
            return
        if "to_world" in p and p["to_world"] is None:
            p["to_world"] = xf.identity()
        if obj.type == "point" and p["position"] is not None:
            if "to_world" in node.props:
                raise scene_error("point emitter: give either 'position' or 'to_world'",
                                  _loc(node, "position"))
            p["to_world"] = xf.translate(p["position"])
        if obj.type == "point":
            p["position"] = p["to_world"][:3, 3].copy()
        if obj.type == "spot" and p["beam_width"] is None:
            p["beam_width"] = p["cutoff_angle"] * 0.75
        if obj.type == "directional":
            if p["direction"] is not None:
                if "to_world" in node.props:
                    raise scene_error("directional emitter: give either 'direction' or "
                                      "'to_world'", _loc(node, "direction"))
                d = p["direction"]
                if not np.any(d):
                    raise scene_error("directional emitter: 'direction' is zero",
                                      _loc(node, "direction"))
                p["to_world"] = xf.look_at([0, 0, 0], d)
            p["direction"] = p["to_world"][:3, 2] / np.linalg.norm(p["to_world"][:3, 2])
        if obj.type == "envmap":
            path = self.file(node, "filename", "environment map")
            if path.suffix.lower() not in BITMAP_FORMATS:
                raise scene_error(f"envmap: image format '{path.suffix}' is not supported; "
                                  f"accepted: {', '.join(BITMAP_FORMATS)}", _loc(node, "filename"))
            p["filename"] = str(path)

    def finish_integrator(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = [i for i, _ in objects.get("integrator", [])]
        if obj.decl is not None:  # a user's plugin (or one given as a file): its own params
            return
        p["nested_names"] = [ch.name or f"_arg_{k}"
                             for k, (_, ch) in enumerate(objects.get("integrator", []))]
        if obj.type == "path":
            if p["max_depth"] < -1:
                raise scene_error("path: 'max_depth' must be -1 (infinite) or >= 0",
                                  _loc(node, "max_depth"))
            if p["rr_depth"] <= 0:
                raise scene_error("path: 'rr_depth' must be > 0", _loc(node, "rr_depth"))
        elif obj.type == "direct":  # Mitsuba's checks of direct.cpp
            ss = p["shading_samples"]
            if ss is not None and (p["emitter_samples"] is not None
                                   or p["bsdf_samples"] is not None):
                raise scene_error("direct: cannot specify both 'shading_samples' and "
                                  "('emitter_samples' and/or 'bsdf_samples')", node.loc)
            for k in ("emitter_samples", "bsdf_samples"):
                if p[k] is None:
                    p[k] = ss if ss is not None else 1
                if p[k] < 0:
                    raise scene_error(f"direct: '{k}' must be >= 0", _loc(node, k))
            if p["emitter_samples"] + p["bsdf_samples"] == 0:
                raise scene_error("direct: must have at least 1 BSDF or emitter sample",
                                  node.loc)
        elif obj.type == "aov":
            aovs = []
            for item in (s.strip() for s in p["aovs"].split(",")):
                name, sep, kind = item.partition(":")
                if not sep or not name.strip() or kind.strip() not in AOV_TYPES:
                    raise scene_error(f"aov: bad entry '{item}' in 'aovs'; write name:type with "
                                      f"type one of {', '.join(AOV_TYPES)}", _loc(node, "aovs"))
                aovs.append((name.strip(), kind.strip()))
            p["aov_list"] = aovs

    def finish_sensor(self, obj: Sensor, node: ObjectNode, objects: dict) -> None:
        one = {"width": 1, "height": 1} if obj.type in METERS else {}  # a one-pixel film
        obj.film = objects["film"][0][0] if objects["film"] else self.default("film", "hdrfilm",
                                                                                **one)
        obj.sampler = objects["sampler"][0][0] if objects["sampler"] else None
        finish_sensor(obj, lambda k: _loc(node, k))

    def finish_film(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = []
        p["rfilter"] = (objects["rfilter"][0][0] if objects["rfilter"]
                        else self.default("rfilter", "gaussian"))
        for k in ("width", "height"):
            if p[k] <= 0:
                raise scene_error(f"hdrfilm: '{k}' must be positive", _loc(node, k))
        p["crop_width"] = p["width"] if p["crop_width"] is None else p["crop_width"]
        p["crop_height"] = p["height"] if p["crop_height"] is None else p["crop_height"]
        for axis, size in (("x", "width"), ("y", "height")):
            off, crop = p[f"crop_offset_{axis}"], p[f"crop_{size}"]
            if off < 0 or crop <= 0 or off + crop > p[size]:
                raise scene_error(f"hdrfilm: invalid crop window: crop_offset_{axis}={off} and "
                                  f"crop_{size}={crop} do not fit in {size}={p[size]}",
                                  _loc(node, f"crop_{size}" if f"crop_{size}" in node.props
                                       else f"crop_offset_{axis}"))

    def finish_rfilter(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        for k, v in obj.params.items():
            if v <= 0:
                raise scene_error(f"rfilter '{obj.type}': '{k}' must be positive", _loc(node, k))

    def finish_sampler(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        finish_sampler(obj, lambda k: _loc(node, k))


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


def _param_str(node: ObjectNode, name: str) -> str:
    """A string parameter as the scene wrote it (the caller checked it is present)."""
    return str(node.props[name].value)


def _loc(node: ObjectNode, name: str) -> Loc:
    """The line of parameter ``name`` if the scene gave it, else the object's line."""
    if name in node.props:
        return node.props[name].loc
    for ch in node.children:
        if ch.name == name:
            return ch.loc
    return node.loc


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
