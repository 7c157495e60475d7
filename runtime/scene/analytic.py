"""Analytic ``sphere`` and ``disk`` shapes, with Mitsuba 3's conventions.

The renderer intersects them exactly (Embree user geometry, rdsl.runtime.embree_user) and
shades them from their analytic surface (stdlib/render/geometry.rdsl).  A shape with
``<boolean name="triangulate" value="true"/>`` (an rdsl extension), or every shape when the
scene is loaded with ``triangulate=True`` (``rdsl render --triangulate``), is rendered from
its triangle mesh instead, which the loader builds for every shape anyway.

- sphere: ``to_world`` composed with ``center`` and ``radius``; the center is where it takes
  the origin and the radius the length of its image of (1, 0, 0).  As in Mitsuba a shear or
  a non-uniform scale is warned about (the shape stays a sphere of that radius), and a
  mirroring transform flips the normals.  uv = (phi / 2pi, theta / pi) of the point in object
  space (``to_object`` = the inverse of the whole transform, so a rotation turns the uvs).
- disk: the unit disk at z = 0 placed by any affine ``to_world`` (an ellipse under a
  non-uniform scale); its normal is ``to_world`` applied to the normal (0, 0, 1), uv = (r,
  phi / 2pi) of the local point, area = pi |dp/du x dp/dv|.
- sdfgrid: Mitsuba's SDF grid, samples ``grid`` (z, y, x) over the unit cube placed by
  ``to_world``; ``smooth`` picks Mitsuba's smooth shading normals over the interpolant's
  gradient (``normals="analytic"``).  No area: it cannot be an emitter (nor in Mitsuba).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# geometry.rdsl's shape kinds: 0 a triangle mesh, 3 an instanced one, 4 an SDF grid, 5 and 6
# the curves
KINDS = {"sphere": 1, "disk": 2, "sdfgrid": 4, "linearcurve": 5, "bsplinecurve": 6}


@dataclass
class Analytic:
    """An analytic shape in world space (``to_world`` is the full 4x4 placement)."""

    kind: str
    to_world: np.ndarray
    flip_normals: bool = False
    grid: np.ndarray | None = None  # sdfgrid: float32 samples (z, y, x)
    smooth: bool = True  # sdfgrid: Mitsuba's `normals` = "smooth" (else "analytic")

    @property
    def linear(self) -> np.ndarray:
        return np.asarray(self.to_world, np.float64)[:3, :3]

    @property
    def center(self) -> np.ndarray:
        return np.asarray(self.to_world, np.float64)[:3, 3].copy()

    @property
    def radius(self) -> float:
        """The sphere's radius: the length of ``to_world``'s image of (1, 0, 0)."""
        return float(np.linalg.norm(self.linear[:, 0]))

    @property
    def flipped(self) -> bool:
        """Whether the normals point inwards (a sphere's mirroring transform flips them)."""
        mirrored = self.kind == "sphere" and np.linalg.det(self.linear) < 0
        return bool(self.flip_normals) != bool(mirrored)

    @property
    def disk_normal(self) -> np.ndarray:
        """The disk's unit normal, ``flip_normals`` applied."""
        n = np.linalg.inv(self.linear).T @ np.array([0.0, 0.0, 1.0])
        n = n / np.linalg.norm(n)
        return -n if self.flip_normals else n

    @property
    def area(self) -> float:
        if self.kind == "sphere":
            return 4.0 * math.pi * self.radius ** 2
        if self.kind == "sdfgrid":
            return 0.0
        return math.pi * float(np.linalg.norm(np.cross(self.linear[:, 0], self.linear[:, 1])))

    def uniform_scale_problem(self) -> str | None:
        """Why a sphere's transform is not a similarity (Mitsuba warns), or None."""
        if self.kind != "sphere":
            return None
        lin = self.linear
        gram = lin.T @ lin
        r2 = self.radius ** 2
        if not np.allclose(gram, r2 * np.eye(3), rtol=0, atol=1e-5 * r2):
            off = gram - np.diag(np.diag(gram))
            return ("'to_world' shouldn't contain any shearing" if np.abs(off).max() > 1e-5 * r2
                    else "'to_world' shouldn't contain non-uniform scaling")
        return None
