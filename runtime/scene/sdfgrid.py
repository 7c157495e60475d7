"""The ``sdfgrid`` shape's data: its samples from a ``.vol`` file (Mitsuba's volume grid
format, runtime/scene/volgrid.py), checked as Mitsuba 3 checks them.

The grid spans the unit cube [0, 1]^3 of object space (``to_world`` places it); the renderer
intersects it through an Embree user geometry whose callback runs rdsl code
(stdlib/render/sdfgrid.rdsl) and shades it from the interpolant's gradient or Mitsuba's
smooth normals (``normals``).  ``load_dict`` takes the samples as a ``grid`` array (Mitsuba's
tensor of shape (z, y, x, 1)) and hands them over as a ``.vol`` file (scene/dicts.py).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import meshes
from .meshes import Mesh
from .volgrid import VolError, read_vol


def check_grid(grid: np.ndarray, what: str) -> np.ndarray:
    """The samples (z, y, x) of a grid of shape (z, y, x, 1) or (z, y, x), or a ValueError
    that says what is wrong, prefixed with ``what``."""
    g = np.asarray(grid, np.float32)
    if g.ndim == 4:
        if g.shape[3] != 1:
            raise ValueError(f"{what} has {g.shape[3]} channels, expected 1")
        g = g[..., 0]
    if g.ndim != 3:
        raise ValueError(f"{what} has shape {g.shape}, expected (z, y, x, 1)")
    if min(g.shape) < 2:
        raise ValueError(f"{what} has {g.shape[2]} x {g.shape[1]} x {g.shape[0]} samples, "
                         "expected at least 2 along each axis")
    if not np.all(np.isfinite(g)):
        raise ValueError(f"{what} holds NaN or infinite samples")
    if g.size >= 1 << 24:
        raise ValueError(f"{what} has {g.size} samples, more than rdsl's limit of 2^24")
    return np.ascontiguousarray(g)


def has_surface(g: np.ndarray) -> bool:
    """Whether some voxel has corners of both signs (Mitsuba refuses a grid without one)."""
    corners = [g[z:g.shape[0] - 1 + z, y:g.shape[1] - 1 + y, x:g.shape[2] - 1 + x]
               for z in (0, 1) for y in (0, 1) for x in (0, 1)]
    lo, hi = np.min(corners, axis=0), np.max(corners, axis=0)
    return bool(np.any((lo <= 0) & (hi >= 0)))


def load_grid(path: Path) -> np.ndarray:
    """The checked samples of the ``.vol`` file ``path`` (ValueError or OSError)."""
    try:
        data, _ = read_vol(path)
    except VolError as e:
        raise ValueError(f"not a Mitsuba volume grid (.vol) file: {e}") from None
    g = check_grid(data, "the grid")
    if not has_surface(g):
        raise ValueError("the grid has no voxel with samples of both signs (no surface)")
    return g


def box_mesh() -> Mesh:
    """The unit cube [0, 1]^3 as a mesh: the shape's bounds for the scene (camera defaults,
    scene box); it is never drawn."""
    m = meshes.cube()
    m.vertices = (0.5 * (m.vertices + 1.0)).astype(np.float32)
    return m


__all__ = ["box_mesh", "check_grid", "has_surface", "load_grid"]
