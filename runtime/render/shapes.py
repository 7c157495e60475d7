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


__all__ = ["FLAGS", "INSTANCED", "INSTANCED_KIND", "KINDS", "RECORD", "instance_record",
           "shape_record", "user_geometry"]
