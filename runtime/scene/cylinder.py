"""Mitsuba 3's ``cylinder`` shape (shapes/cylinder.cpp): an open tube of ``radius`` from
``p0`` to ``p1``, placed by ``to_world`` after that.

In object space it is x^2 + y^2 = 1, 0 <= z <= 1, with the outward normal (x, y, 0) and
uv = (phi / 2pi, z), phi = atan2(y, x) in [0, 2pi).  Mitsuba maps it to ``p0``..``p1`` by
``translate(p0) * to_frame(Frame(d / |d|)) * scale(radius, radius, |d|)``, d = p1 - p0,
the frame being Duff et al.'s ``coordinate_system`` (so that a texture's seam lies where
Mitsuba's does).  rdsl renders it as a mesh of ``SEGMENTS`` quads with the analytic
normals at its vertices and the seam's vertices duplicated (u = 0 and u = 1); the
polygon's area and silhouette are within 1e-4 of the circle's.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from .errors import scene_error
from .meshes import Mesh

SEGMENTS = 256


def coordinate_system(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Duff et al.'s orthonormal (s, t) around the unit vector ``n`` (Mitsuba's, and
    stdlib/frame.rdsl's)."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    s = np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])
    t = np.array([b, sign + n[1] * n[1] * a, -n[1]])
    return s, t


def cylinder_frame(p: dict[str, Any], loc: Callable[[str], Loc]) -> np.ndarray:
    """The object-to-``to_world``-space matrix of the cylinder's ``p0``, ``p1`` and
    ``radius`` (``loc(name)``: the line of a parameter, for errors)."""
    if p["radius"] <= 0:
        raise scene_error("cylinder: 'radius' must be positive", loc("radius"))
    p0 = np.zeros(3) if p["p0"] is None else np.asarray(p["p0"], np.float64)
    p1 = np.array([0.0, 0.0, 1.0]) if p["p1"] is None else np.asarray(p["p1"], np.float64)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    if length == 0:
        raise scene_error("cylinder: 'p0' and 'p1' are the same point", loc("p1"))
    n = d / length
    s, t = coordinate_system(n)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = s * p["radius"], t * p["radius"], d, p0
    p["p0"], p["p1"] = p0, p1
    return m


def cylinder_mesh(segments: int = SEGMENTS) -> Mesh:
    """The unit tube in object space: two rings of ``segments + 1`` vertices."""
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    ring = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    v = np.vstack([np.column_stack([ring, np.zeros(len(phi))]),
                   np.column_stack([ring, np.ones(len(phi))])])
    normals = np.column_stack([np.vstack([ring, ring]), np.zeros(len(v))])
    u = phi / (2.0 * np.pi)
    uv = np.vstack([np.column_stack([u, np.zeros_like(u)]),
                    np.column_stack([u, np.ones_like(u)])])
    i = np.arange(segments)
    w = segments + 1
    # counter-clockwise seen from outside: (bottom i, bottom i+1, top i+1), (.., top i)
    f = np.vstack([np.stack([i, i + 1, w + i + 1], axis=1),
                   np.stack([w + i + 1, w + i, i], axis=1)])
    return Mesh(v, f, normals, uv)
