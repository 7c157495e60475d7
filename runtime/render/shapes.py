"""Analytic shapes for the renderer: the Embree user geometry that intersects a sphere or a
disk, and the record in ``P`` from which stdlib/render/geometry.rdsl shades and samples it.

Record layout (``RECORD`` floats; geometry.rdsl documents it too):

    [0:12]  rows of to_world (3 x 4)         [12:24] rows of to_object (3 x 4)
    [24:27] sphere: center; disk: normal (flip_normals applied)
    [27]    sphere: radius                   [28] +1, or -1 when the normals are flipped
    [29]    surface area
"""

from __future__ import annotations

import numpy as np

from ..embree_user import UserShape
from ..embree_user import disk as user_disk
from ..embree_user import sphere as user_sphere
from ..scene.analytic import KINDS, Analytic

RECORD = 32  # floats per analytic shape in P (geometry.rdsl: shape_record_size())
# G's flag bits of the analytic kinds and the curves (runtime/scene/curves.py)
FLAGS = {"sphere": 4, "disk": 8, "linearcurve": 32, "bsplinecurve": 64}
INSTANCED = 16  # G's flag bit of a shapegroup's mesh, drawn by an instance
INSTANCED_KIND = 3  # geometry.rdsl's shape kind of those


def shape_record(shape: Analytic) -> np.ndarray:
    """The shape's record for ``P``."""
    m = np.asarray(shape.to_world, np.float64)
    rec = np.zeros(RECORD)
    rec[0:12] = m[:3, :4].reshape(-1)
    rec[12:24] = np.linalg.inv(m)[:3, :4].reshape(-1)
    if shape.kind == "sphere":
        rec[24:27], rec[27] = shape.center, shape.radius
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
    return user_disk(shape.to_world)


__all__ = ["FLAGS", "INSTANCED", "INSTANCED_KIND", "KINDS", "RECORD", "instance_record",
           "shape_record", "user_geometry"]
