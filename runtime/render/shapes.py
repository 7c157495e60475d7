"""Analytic shapes for the renderer: the Embree user geometry that intersects a sphere or a
disk, and the record in ``P`` from which stdlib/render/geometry.rdsl shades and samples it.

Record layout (``RECORD`` floats; geometry.rdsl documents it too):

    [0:12]  rows of to_world (3 x 4)         [12:24] rows of to_object (3 x 4)
    [24:27] sphere: center; disk: normal (flip_normals applied)
    [27]    sphere: radius                   [28] +1, or -1 when the normals are flipped
    [29]    surface area
    sdfgrid: [24:27] its sample counts nx, ny, nz, [30] 1 for smooth normals, and its
    samples after the record (stdlib/render/sdfgrid.rdsl), so its record is longer
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..embree_user import UserShape
from ..embree_user import disk as user_disk
from ..embree_user import sdfgrid as user_sdfgrid
from ..embree_user import sphere as user_sphere
from ..scene.analytic import KINDS, Analytic

RECORD = 32  # floats per analytic shape in P (geometry.rdsl: shape_record_size())
# G's flag bits of the analytic kinds, the SDF grid and the curves (runtime/scene/curves.py)
FLAGS = {"sphere": 4, "disk": 8, "sdfgrid": 32, "linearcurve": 64, "bsplinecurve": 128}
INSTANCED = 16  # G's flag bit of a shapegroup's mesh, drawn by an instance
INSTANCED_KIND = 3  # geometry.rdsl's shape kind of those
# G's flags above the kinds' bits: Mitsuba 3's numbers of the shape, for the `aov`
# integrator's prim_index and shape_index (geometry.rdsl; :func:`mitsuba_numbers`)
MI_ANALYTIC = 256  # a shape Mitsuba does not build of triangles: its prim_index is 0
# a rectangle: Mitsuba 3.9 cuts it along the other diagonal, its triangle 1 where u + v > 1
# (rdsl keeps its own two triangles, which the reference images are rendered with)
MI_RECTANGLE = 512
MI_INDEX_SHIFT = 10  # the shape's place in Mitsuba's shape list, from 1
MI_INDEX_MAX = (1 << (31 - MI_INDEX_SHIFT)) - 1
# the shapes Mitsuba 3 does not make of triangles (not a `Mesh`); rdsl renders a cylinder,
# and a triangulated sphere or disk, from triangles all the same
MI_NON_MESH = ("sphere", "disk", "cylinder", "instance", "sdfgrid", "linearcurve",
               "bsplinecurve")
MI_ONE_PRIM = ("sphere", "disk", "cylinder")  # prim_index 0 (a curve's is its segment's)


def shape_record(shape: Analytic) -> np.ndarray:
    """The shape's record for ``P`` (an sdfgrid's samples follow it)."""
    m = np.asarray(shape.to_world, np.float64)
    grid = shape.grid if shape.kind == "sdfgrid" else None
    rec = np.zeros(RECORD + (0 if grid is None else grid.size))
    rec[0:12] = m[:3, :4].reshape(-1)
    rec[12:24] = np.linalg.inv(m)[:3, :4].reshape(-1)
    if shape.kind == "sphere":
        rec[24:27], rec[27] = shape.center, shape.radius
    elif grid is not None:
        rec[24:27] = grid.shape[::-1]
        rec[30] = 1.0 if shape.smooth else 0.0
        rec[RECORD:] = grid.reshape(-1)
    else:
        rec[24:27] = shape.disk_normal
    rec[28] = -1.0 if shape.flipped else 1.0
    rec[29] = shape.area
    return rec


def sdf_voxel_ranks(grid: np.ndarray) -> np.ndarray:
    """Mitsuba 3's prim_index of each voxel of an SDF grid of samples (z, y, x), in
    sdfgrid.rdsl's numbering x + (nx - 1) (y + (ny - 1) z): Mitsuba makes a primitive of
    each voxel that holds surface (corners of both signs, a zero counts as both), in that
    order, so a voxel's number is its rank among those (-1 for the others)."""
    g = np.asarray(grid, np.float32)
    nz, ny, nx = g.shape
    corners = np.stack([g[z:nz - 1 + z, y:ny - 1 + y, x:nx - 1 + x]
                        for z in (0, 1) for y in (0, 1) for x in (0, 1)])
    held = ((corners.min(axis=0) <= 0) & (corners.max(axis=0) >= 0)).reshape(-1)
    return np.where(held, np.cumsum(held) - 1, -1)


def instance_record(to_world: np.ndarray) -> np.ndarray:
    """An instance's record for ``P`` (geometry.rdsl): rows of to_world, rows of its inverse
    transpose (normals) and the sign of its determinant."""
    m = np.asarray(to_world, np.float64)
    rec = np.zeros(RECORD)
    rec[0:12] = m[:3, :4].reshape(-1)
    normal = np.zeros((3, 4))
    normal[:, :3] = np.linalg.inv(m[:3, :3]).T
    rec[12:24] = normal.reshape(-1)
    rec[24] = 1.0 if np.linalg.det(m[:3, :3]) > 0 else -1.0
    return rec


def user_geometry(shape: Analytic) -> UserShape:
    """The Embree user geometry that intersects ``shape``."""
    if shape.kind == "sphere":
        return user_sphere(shape.center, shape.radius)
    if shape.kind == "sdfgrid":
        return user_sdfgrid(shape_record(shape), shape.to_world)
    return user_disk(shape.to_world)


def mitsuba_numbers(shapes: list[Any]) -> list[int]:
    """Each of the scene's shapes (in declaration order) as G's flag bits of its number in
    Mitsuba 3, the `aov` integrator's shape_index.  Mitsuba 3.9 numbers a hit's shape by its
    place in the scene's shape list, from 1: the shapes that are not meshes (spheres, disks,
    cylinders, instances, curves, SDF grids) first, in declaration order, then the meshes
    (obj, ply, serialized, rectangle, cube), whose order in that list changes from one load
    to the next in Mitsuba; rdsl keeps their declaration order.  A place beyond
    MI_INDEX_MAX is given as 0."""
    order = ([k for k, s in enumerate(shapes) if s.type in MI_NON_MESH]
             + [k for k, s in enumerate(shapes) if s.type not in MI_NON_MESH])
    bits = [0] * len(shapes)
    for place, k in enumerate(order, 1):
        bits[k] = (place if place <= MI_INDEX_MAX else 0) << MI_INDEX_SHIFT
    return bits


def one_prim(shape: Any) -> int:
    """G's flag bit of a shape whose prim_index Mitsuba gives as 0 (it is not made of
    triangles there), whether or not rdsl draws it from triangles, or of a rectangle."""
    if shape.type == "rectangle":
        return MI_RECTANGLE
    return MI_ANALYTIC if shape.type in MI_ONE_PRIM else 0


__all__ = ["FLAGS", "INSTANCED", "INSTANCED_KIND", "KINDS", "MI_ANALYTIC", "MI_INDEX_SHIFT",
           "RECORD", "instance_record", "mitsuba_numbers", "one_prim", "sdf_voxel_ranks",
           "shape_record", "user_geometry"]
