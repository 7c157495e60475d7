"""A scene's shapes flattened into the buffers the kernels read (layout in
stdlib/render/geometry.rdsl and stdlib/render/lights.rdsl), with its BSDF, texture and emitter
instances, and the items Embree builds its scene from.

An instance of a shapegroup (``instancing``, the Embree build) keeps the group's triangles
once, in the group's space, and adds per instance only a G entry per mesh of the group and a
record of its transform: 10^4 instances of a mesh cost memory for one.  Without
``instancing`` (the rdsl BVH, which has no instances) every instance is flattened into a
world-space copy of its group's meshes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from ...core.color import RGB, ColorModel
from ...core.scene_spec import Instance
from ..embree_curves import EmbreeCurves
from ..embree_instance import EmbreeGroup, EmbreeInstance
from ..scene import meshes as scene_meshes
from .bsdfs import bsdf_instance, scene_bsdfs
from .colors import spectrum_value
from .declared import declared_instance
from .emitters import EmitterTables, emitter_tables
from .measured import check_measured_variant
from .shapes import FLAGS as SHAPE_FLAGS
from .shapes import (
    INSTANCED,
    instance_record,
    mitsuba_numbers,
    one_prim,
    sdf_voxel_ranks,
    shape_record,
    user_geometry,
)
from .shapes import KINDS as SHAPE_KINDS
from .textures import TextureTable


@dataclass
class SceneBuffers:
    """The scene's triangles and lights, flattened for the kernels (layout in
    stdlib/render/geometry.rdsl and stdlib/render/lights.rdsl)."""

    P: np.ndarray
    N: np.ndarray
    UV: np.ndarray
    F: np.ndarray
    G: np.ndarray
    lights: EmitterTables  # LC, LT and the emitter tables
    meshes: list[Any] = field(default_factory=list)  # what the Embree scene is built from
    T: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))  # texels
    textures: list[Instance] = field(default_factory=list)
    # the BVH of `--accel bvh` (stdlib/render/bvh.rdsl; an empty tree with Embree)
    BV: np.ndarray = field(default_factory=lambda: np.zeros(1, np.float32))
    BI: np.ndarray = field(default_factory=lambda: np.zeros(4, np.int32))

    @property
    def nlight(self) -> int:
        """The number of emitters (an area-lit shape counts as one)."""
        return self.lights.nemitter

    def args(self) -> list[np.ndarray]:
        return [self.P, self.N, self.UV, self.F, self.G, self.lights.LC, self.lights.LT,
                self.T, *self.lights.args(), self.BV, self.BI]


def _flat(v: np.ndarray, f: np.ndarray, normals: Any) -> bool:
    """Whether every triangle's vertex normals are its geometric normal (a rectangle, a
    cube): interpolating them gives that normal again, so the mesh is shaded with face
    normals, and the kernels skip reading and interpolating them."""
    n = np.asarray(normals, np.float64)[f]  # (M, 3 vertices, 3)
    tri = v.astype(np.float64)[f]
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-30)
    n = n / np.maximum(np.linalg.norm(n, axis=2, keepdims=True), 1e-30)
    return bool(len(f)) and bool(np.all(np.einsum("mkj,mj->mk", n, ng) > 1 - 1e-6))


def area_instance(em: Any, textures: TextureTable) -> Instance:
    """The ``area`` emitter instance of an emissive shape (its radiance may be a texture),
    or the instance of a user's emitter plugin."""
    if getattr(em, "decl", None) is not None:
        return declared_instance(em, textures, illuminant=True)
    if em.type != "area":
        raise CompileError(f"emitter `{em.type}` is not supported by the renderer yet", em.loc)
    radiance = em.params["radiance"]
    if getattr(radiance, "category", None) == "texture":
        return Instance(em.type, {"radiance": textures.ref(radiance, "area.radiance",
                                                           "emitted")})
    return Instance(em.type, {"radiance": spectrum_value(
        radiance, "area.radiance", illuminant=True, loc=em.loc)})


class _Flattener:
    """Appends shapes to the buffers; G row k is Embree geometry ID k."""

    def __init__(self, model: ColorModel) -> None:
        self.model = model
        self.P: list[np.ndarray] = []
        self.N: list[np.ndarray] = []
        self.UV: list[np.ndarray] = []
        self.F: list[np.ndarray] = []
        self.G: list[np.ndarray] = []
        self.bsdfs: list[Instance] = []
        self.bsdf_ids: dict[int, int] = {}
        self.textures = TextureTable()
        self.emitters: list[Instance] = []
        self.lights: list[tuple[int, int, float]] = []  # (triangle, G row, area)
        # (G row, G column, record) of the records that follow the vertices in P
        self.records: list[tuple[int, int, np.ndarray]] = []
        self.analytic: dict[int, Any] = {}  # G row -> Analytic, of the area-lit ones
        self.curves: list[tuple[int, Any]] = []  # (G row, Curves)
        self.items: list[Any] = []  # Embree's: (vertices, faces), user shapes, instances
        # id(shapegroup) -> (its Embree group, its meshes' (first triangle, bsdf, flags))
        self.groups: dict[int, tuple[EmbreeGroup, list[tuple[int, int, int]]]] = {}
        self.nv = self.nt = 0
        self.tri_meshes: list[tuple[int, Any, Any]] = []  # (first triangle, mesh, BSDF)

    def bsdf_id(self, bsdf: Any, shape_name: str) -> int:
        """The index of the BSDF's instance, made at its first shape: one without an id is
        named as Mitsuba's ``mi.traverse`` names it, ``<shape>.bsdf`` (so two anonymous
        BSDFs of one type, or the black diffuse of two area lights' shapes, do not take one
        name)."""
        key = id(bsdf)
        if key not in self.bsdf_ids:
            self.bsdf_ids[key] = len(self.bsdfs)
            name = bsdf.id or f"{shape_name}.bsdf"
            with self.textures.owned_by(name):  # its textures without ids: <name>.<param>
                self.bsdfs.append(bsdf_instance(bsdf, self.textures,
                                                prefix=None if bsdf.id else name))
        return self.bsdf_ids[key]

    def triangles(self, m: Any) -> tuple[np.ndarray, np.ndarray, int]:
        """Append the mesh's vertices and triangles: (vertices, faces, flags)."""
        v = np.ascontiguousarray(m.vertices, np.float32)
        f = np.ascontiguousarray(m.faces, np.uint32)
        flags = 0
        self.P.append(v.reshape(-1))
        if m.normals is not None and not m.face_normals and not _flat(v, f, m.normals):
            self.N.append(np.asarray(m.normals, np.float32).reshape(-1))
            flags |= 1
        else:
            self.N.append(np.zeros(3 * len(v), np.float32))
        if m.uvs is not None:
            self.UV.append(np.asarray(m.uvs, np.float32).reshape(-1))
            flags |= 2
        else:
            self.UV.append(np.zeros(2 * len(v), np.float32))
        self.F.append((f.astype(np.int64) + self.nv).astype(np.int32).reshape(-1))
        self.nv += len(v)
        self.nt += len(f)
        return v, f, flags

    def shape(self, shape_index: int, shape: Any, triangulate: bool) -> None:
        name = shape.id or f"shape{shape_index}"
        bsdf = self.bsdf_id(shape.bsdf, name)
        emitter = -1
        if shape.emitter is not None:
            emitter = len(self.emitters)
            with self.textures.owned_by(f"{name}.emitter"):
                self.emitters.append(area_instance(shape.emitter, self.textures))
            # named as Mitsuba's traverse names it (`light.emitter.radiance`)
            self.emitters[-1].name = f"{name}.emitter"
        row = len(self.G)
        if shape.curves is not None:  # G's first entry is set by finish(), with the curves
            c = shape.curves
            self.items.append(EmbreeCurves(c.kind, c.points, c.segments))
            self.curves.append((row, c))
            self.G.append(np.array([-1, bsdf, emitter, SHAPE_FLAGS[c.kind]], np.int32))
            return
        analytic = shape.analytic  # an sdfgrid has no triangles to render instead
        if triangulate and analytic is not None and analytic.kind != "sdfgrid":
            analytic = None
        if analytic is not None:  # G's first entry is set by finish(), with the records
            self.items.append(user_geometry(analytic))
            record = shape_record(analytic)
            if analytic.kind == "sdfgrid":  # then Mitsuba's numbers of its voxels
                record = np.r_[record, sdf_voxel_ranks(analytic.grid)]
            self.records.append((row, 0, record))
            if emitter >= 0:
                self.lights.append((-1, row, analytic.area))
                self.analytic[row] = analytic
            flags = SHAPE_FLAGS[analytic.kind] | one_prim(shape)
            self.G.append(np.array([-1, bsdf, emitter, flags], np.int32))
            return
        first = self.nt
        v, f, flags = self.triangles(shape.mesh)
        self.tri_meshes.append((first, shape.mesh, shape.bsdf))
        self.items.append((v, f))
        if emitter >= 0:
            tri = v[f]
            areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                         axis=1)
            self.lights += [(first + i, row, float(a)) for i, a in enumerate(areas)]
        self.G.append(np.array([first, bsdf, emitter, flags | one_prim(shape)], np.int32))

    def instance(self, shape: Any) -> None:
        """One G entry per mesh of the shapegroup and a record of the transform; the group's
        triangles and its Embree scene are made at its first instance."""
        group = shape.children[0]
        if id(group) not in self.groups:
            entries, parts = [], []
            for k, child in enumerate(group.children):
                first = self.nt
                v, f, flags = self.triangles(child.mesh)
                self.tri_meshes.append((first, child.mesh, child.bsdf))
                parts.append((v, f))
                child_name = child.id or f"{group.id or 'shapegroup'}.shape{k}"
                entries.append((first, self.bsdf_id(child.bsdf, child_name),
                                flags | INSTANCED | one_prim(child)))
            self.groups[id(group)] = (EmbreeGroup(parts), entries)
        embree_group, entries = self.groups[id(group)]
        if not entries:
            return  # an empty shapegroup draws nothing
        self.items.append(EmbreeInstance(embree_group, shape.params["to_world"]))
        record = instance_record(shape.params["to_world"])
        for first, bsdf, flags in entries:
            self.records.append((len(self.G), 2, record))
            self.G.append(np.array([first, bsdf, 0, flags], np.int32))

    def curve_data(self, p_offset: int) -> None:
        """Each curve shape's control points at the end of P and, at the end of F, its
        segment count, control point count and each segment's offset in P of its first
        control point (geometry.rdsl); G's first entry is the offset of those in F."""
        f_offset = 3 * self.nt
        for row, c in self.curves:
            entries = np.r_[len(c.segments), len(c.points),
                            p_offset + 4 * c.segments.astype(np.int64)]
            entries = np.r_[entries, np.zeros(-len(entries) % 3, np.int64)]  # F: triples
            if p_offset + 4 * len(c.points) >= 2**31:
                raise CompileError("the scene's curves are too large for 32-bit offsets",
                                   None)
            self.G[row][0] = f_offset
            self.P.append(c.points.reshape(-1))
            self.F.append(entries.astype(np.int32))
            p_offset += 4 * len(c.points)
            f_offset += len(entries)

    def finish(self, desc: Any) -> SceneBuffers:
        self.textures.fill_attributes(self.tri_meshes)
        # the records follow the vertices in P; their G entries point at them
        analytic_lights = {}
        offset = 3 * self.nv
        for row, column, record in self.records:
            self.G[row][column] = offset
            self.P.append(record)
            if row in self.analytic:
                a = self.analytic[row]
                analytic_lights[row] = (SHAPE_KINDS[a.kind], offset, a.area)
            offset += len(record)

        self.curve_data(offset)  # after the records, which vary in length (sdfgrid)

        def cat(xs: list[np.ndarray], dt: Any) -> np.ndarray:  # never empty: kernels need memory
            return np.ascontiguousarray(np.concatenate(xs) if xs else np.zeros(1, dt), dt)

        bufs = SceneBuffers(cat(self.P, np.float32), cat(self.N, np.float32),
                            cat(self.UV, np.float32), cat(self.F, np.int32),
                            cat(self.G, np.int32),
                            emitter_tables(desc, self.lights, len(self.emitters),
                                           analytic_lights, self.model, self.textures),
                            self.items)
        bufs.T, bufs.textures = self.textures.buffer(self.model), self.textures.instances
        return bufs


def world_copies(shape: Any) -> list[Any]:
    """An instance's shapegroup as world-space shapes of their own (for the rdsl BVH)."""
    m = shape.params["to_world"]
    return [replace(child, mesh=scene_meshes.to_world(child.mesh, m, False,
                                                      child.mesh.face_normals))
            for child in shape.children[0].children]


# the most triangles that copies of instances may add where they cannot be instanced (the
# rdsl BVH): beyond it the copies' memory and the BVH's build time are the problem
MAX_COPIED_TRIANGLES = 20_000_000


def _check_copies(shapes: list[Any]) -> None:
    instances = [s for s in shapes if s.type == "instance"]
    total = sum(len(c.mesh.faces) for s in instances for c in s.children[0].children)
    if total > MAX_COPIED_TRIANGLES:
        raise CompileError(f"the rdsl BVH (--accel bvh) has no instances: the scene's "
                           f"{len(instances)} instances would be copied into {total:,} "
                           f"triangles (more than {MAX_COPIED_TRIANGLES:,}); render on the CPU "
                           "with Embree (--accel embree), which stores each shapegroup once",
                           instances[0].loc)


def flatten(desc: Any, triangulate: bool = False, model: ColorModel = RGB,
            instancing: bool = True) -> tuple[SceneBuffers, list[Instance], list[Instance]]:
    """Concatenate the scene's meshes and collect its BSDF and emitter instances.  Analytic
    spheres and disks become Embree user geometry with a record in ``P`` (after the
    vertices), unless ``triangulate`` asks for every shape's triangle mesh.  Instances of a
    shapegroup share its triangles (``instancing``) or become copies in world space.
    Colours in buffers are stored as ``model`` reads them (runtime/render/colors.py)."""
    if not instancing:
        _check_copies(desc.shapes)
    check_measured_variant(scene_bsdfs(desc), model)
    fl = _Flattener(model)
    numbers = mitsuba_numbers(desc.shapes)
    for shape_index, shape in enumerate(desc.shapes):
        first_row = len(fl.G)
        if shape.type != "instance":
            fl.shape(shape_index, shape, triangulate)
        elif instancing:
            fl.instance(shape)
        else:
            for copy in world_copies(shape):
                fl.shape(shape_index, copy, triangulate)
        for row in fl.G[first_row:]:  # Mitsuba's numbers of the shape, in G's high flags
            row[3] |= numbers[shape_index]
    return fl.finish(desc), fl.bsdfs, fl.emitters
