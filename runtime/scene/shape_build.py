"""The loader's shapes: each shape's triangle mesh in world space (or its analytic sphere or
disk), its BSDF, its area emitter and a nested irradiancemeter.

:class:`ShapeFinisher` is a mixin of the loader's builder (loader.py), which calls
``finish_shape`` once a shape's parameters and nested objects are collected.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING

import numpy as np

from ...compiler.ir import Loc
from . import meshes
from . import transform as xf
from .analytic import Analytic
from .curves import CURVE_TYPES, CurveError, read_curves
from .cylinder import cylinder_frame, cylinder_mesh
from .errors import file_loc, scene_error
from .mesh_attributes import check_attributes
from .meshes import MeshError
from .nodes import param_loc as _loc
from .reads import memoized
from .sdfgrid import box_mesh, load_grid
from .sensors import attach_meter
from .xml import ObjectNode

if TYPE_CHECKING:
    from .loader import Shape


# shapes made of shapes: a shapegroup (drawn through its instances), an instance of one,
# and merge (Mitsuba merges its meshes of one BSDF into one; rdsl renders them as they are)
GROUPS = ("shapegroup", "instance", "merge")


class ShapeFinisher:
    """``finish_shape`` (a mixin of the loader's builder)."""

    def finish_group(self, obj: Shape, node: ObjectNode, objects: dict) -> None:
        """A shapegroup's, an instance's or a merge's shapes, checked: an instance draws one
        shapegroup; a shapegroup holds meshes without emitters or sensors (Embree has one
        level of instancing) and its analytic shapes become their triangle meshes."""
        shapes = objects.get("shape", [])
        for child, ch in shapes:
            what = (f"shape '{ch.node.id}' (a '{child.type}')" if ch.is_ref
                    else f"a nested '{child.type}' shape")
            if obj.type == "instance":
                if child.type != "shapegroup":
                    raise scene_error(f"instance: takes a <ref> to a 'shapegroup', got {what}",
                                      ch.loc)
                continue
            if child.type == "shapegroup" or (obj.type == "shapegroup"
                                              and child.type in GROUPS):
                raise scene_error(f"{obj.type}: cannot hold {what} (rdsl instances one level "
                                  "deep: give the shapegroup's shapes directly)", ch.loc)
            if obj.type == "shapegroup" and child.curves is not None:
                raise scene_error(f"shapegroup: cannot hold {what} (rdsl instances triangle "
                                  "meshes only; declare the curves outside the shapegroup)",
                                  ch.loc)
            if obj.type == "shapegroup" and (child.emitter is not None
                                             or child.sensor is not None):
                kind = "an emitter" if child.emitter is not None else "a sensor"
                raise scene_error(f"shapegroup: a shape with {kind} cannot be instanced (as in "
                                  "Mitsuba 3); declare it outside the shapegroup", ch.loc)
            if obj.type == "shapegroup" and child.type == "sdfgrid":
                raise scene_error("shapegroup: rdsl cannot instance an 'sdfgrid' (its groups "
                                  "hold meshes); declare it outside the shapegroup", ch.loc)
        obj.children = [c for c, _ in shapes]
        if obj.type == "shapegroup":
            for child in obj.children:
                child.analytic = None  # the instances' rays are in object space
        if obj.type == "instance":
            m = obj.params["to_world"]
            m = xf.identity() if m is None else m
            if xf.singular(m):
                raise scene_error("instance: 'to_world' is singular or not finite",
                                  _loc(node, "to_world"))
            obj.params["to_world"] = m

    def sdfgrid(self, node: ObjectNode, m: np.ndarray, p: dict) -> Analytic:
        """An sdfgrid's samples, from its ``filename``, checked."""
        grid = self.grid_file(node, p, lambda path: memoized(path, ("sdfgrid",),
                                                             lambda: load_grid(path)))
        return Analytic("sdfgrid", m, False, grid=grid, smooth=p["normals"] == "smooth")

    def finish_shape(self, obj: Shape, node: ObjectNode, objects: dict) -> None:
        if obj.type in GROUPS:
            self.finish_group(obj, node, objects)
            return
        p = obj.params
        m = p["to_world"] if p["to_world"] is not None else xf.identity()
        if xf.singular(m):
            raise scene_error(f"{self.what(node)}: 'to_world' is singular or not finite",
                              _loc(node, "to_world"))
        if obj.type in CURVE_TYPES:
            self.finish_curves(obj, node, objects, m)
            return
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
        elif obj.type == "sdfgrid":
            mesh = box_mesh()
            obj.analytic = self.sdfgrid(node, m, p)
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
            obj.mesh = meshes.to_world(mesh, m, p.get("flip_normals", False), face_normals)
        except MeshError as e:
            raise scene_error(f"{self.what(node)}: {e}", _loc(node, "to_world")) from None
        self.attach(obj, objects)

    def finish_curves(self, obj: Shape, node: ObjectNode, objects: dict, m: np.ndarray) -> None:
        """A linearcurve's or bsplinecurve's control points, read from its file and placed by
        ``to_world``; an emitter or sensor on it is refused (Mitsuba 3 cannot sample a point
        on a curve either: its curves have no ``sample_position``)."""
        path = self.file(node, "filename", "curve")
        try:
            curves = memoized(path, (obj.type,), lambda: read_curves(obj.type, path))
        except CurveError as e:
            loc = Loc(str(path), e.line, 1) if e.line else file_loc(str(path))
            raise scene_error(f"{obj.type}: cannot load curve file '{obj.params['filename']}'"
                              f": {e}", loc) from None
        except OSError as e:
            raise scene_error(f"{obj.type}: cannot read curve file "
                              f"'{obj.params['filename']}': {e.strerror}",
                              _loc(node, "filename")) from None
        obj.params["filename"], obj.params["to_world"] = str(path), m
        obj.curves = curves.with_transform(m)
        for kind in ("emitter", "sensor"):
            if objects.get(kind):
                plugin, ch = objects[kind][0]
                raise scene_error(f"{obj.type}: cannot hold {kind} '{plugin.type}' (a point on "
                                  "a curve cannot be sampled, in Mitsuba 3 as in rdsl)", ch.loc)
        self.attach(obj, objects)

    def attach(self, obj: Shape, objects: dict) -> None:
        """The shape's BSDF, area emitter and irradiancemeter, checked."""
        bsdfs, ems = objects["bsdf"], objects["emitter"]
        # Mitsuba's default (shape.cpp): diffuse, black on an emitter's shape
        obj.bsdf = bsdfs[0][0] if bsdfs else self.default(
            "bsdf", "diffuse", **({"reflectance": 0.0} if ems else {}))
        if ems:
            em, ch = ems[0]
            if em.type != "area" and em.decl is None:
                raise scene_error(f"only an 'area' emitter can be attached to a shape, not "
                                  f"'{em.type}'", ch.loc)
            if obj.type == "sdfgrid":
                raise scene_error("sdfgrid: cannot be an area emitter (nor in Mitsuba 3)",
                                  ch.loc)
            obj.emitter = em
        if objects.get("sensor"):
            if obj.type == "sdfgrid":  # Mitsuba's samples no position on it either
                raise scene_error("sdfgrid: cannot hold a sensor (it has no area to sample)",
                                  objects["sensor"][0][1].loc)
            attach_meter(obj, *objects["sensor"][0])
        problem = check_attributes(obj, f"shape '{obj.id}' ({obj.type})" if obj.id
                                   else f"shape '{obj.type}'")
        if problem is not None:
            raise scene_error(problem[0], problem[1].loc)


def drawn_shapes(shape: Shape) -> list[Shape]:
    """What a shape declared in the scene draws: itself, a merge's shapes, or nothing for a
    shapegroup (its instances draw it)."""
    if shape.type == "shapegroup":
        return []
    if shape.type == "merge":
        return [s for child in shape.children for s in drawn_shapes(child)]
    return [shape]


def shape_points(shape: Shape) -> np.ndarray:
    """Points whose bounding box is the shape's (world space): its vertices, or for an
    instance the corners of its shapegroup's box, transformed."""
    if shape.curves is not None:
        return shape.curves.bounds_points()
    if shape.type != "instance":
        return shape.mesh.vertices
    group = shape.children[0].children
    if not group:
        return np.zeros((0, 3))
    pts = np.vstack([s.mesh.vertices for s in group]).astype(np.float64)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    return xf.apply_points(shape.params["to_world"], corners)
