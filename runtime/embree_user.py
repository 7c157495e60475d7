"""Analytic spheres and disks, and SDF grids, as Embree 4 user geometry, intersected by native
callbacks.

A :class:`UserShape` (from :func:`sphere`, :func:`disk` or :func:`sdfgrid`) holds the block of doubles that its
callbacks read (its ``geometryUserPtr``, laid out by :data:`rdsl.core.embree_abi.USER_BLOCK`,
world space) and registers itself with Embree through ctypes when an
:class:`~rdsl.runtime.embree.EmbreeScene` is built.  The callbacks themselves (bounds,
intersect, occluded; native, so no Python runs per ray) are generated and compiled by the
backend, ``compiler/backends/llvm_shapes.py``, which hands over their addresses.  An SDF
grid's callback calls a kernel written in rdsl (stdlib/render/sdfgrid_kernel.rdsl), compiled
here once per process (and cached on disk like any kernel).
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.embree_abi import USER_BLOCK, USER_BLOCK_DOUBLES, USER_KINDS
from .embree import EmbreeDevice

GEOMETRY_TYPE_USER = 120  # RTC_GEOMETRY_TYPE_USER

_P = ctypes.c_void_p
_SIGNATURES: dict[str, tuple[Any, list[Any]]] = {
    "rtcSetGeometryUserPrimitiveCount": (None, [_P, ctypes.c_uint]),
    "rtcSetGeometryUserData": (None, [_P, _P]),
    "rtcSetGeometryBoundsFunction": (None, [_P, _P, _P]),
    "rtcSetGeometryIntersectFunction": (None, [_P, _P]),
    "rtcSetGeometryOccludedFunction": (None, [_P, _P]),
}


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    for name, (res, args) in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


@dataclass
class UserShape:
    """An analytic shape for :class:`rdsl.runtime.embree.EmbreeScene` (which accepts these
    among its ``(vertices, faces)`` meshes).  Build one with :func:`sphere` or :func:`disk`."""

    kind: str  # one of USER_KINDS
    block: np.ndarray = field(repr=False)  # float64[USER_BLOCK_DOUBLES], the callbacks' data
    keep: tuple[Any, ...] = field(default=(), repr=False)  # what the block's addresses point at

    def new_geometry(self, device: EmbreeDevice, what: str) -> int:
        """A committed ``RTCGeometry`` (the caller attaches and releases it)."""
        # only now: building a scene of meshes never loads the code generator
        from ..compiler.backends.llvm_shapes import callback_addresses

        addrs = callback_addresses()
        lib = _declare(device.lib)
        geom = lib.rtcNewGeometry(device.handle, GEOMETRY_TYPE_USER)
        device.check(f"rtcNewGeometry ({what}, user geometry)")
        data = self.block.ctypes.data
        lib.rtcSetGeometryUserPrimitiveCount(geom, 1)
        lib.rtcSetGeometryUserData(geom, data)
        lib.rtcSetGeometryBoundsFunction(geom, addrs["bounds"], data)
        lib.rtcSetGeometryIntersectFunction(geom, addrs[f"{self.kind}_intersect"])
        lib.rtcSetGeometryOccludedFunction(geom, addrs[f"{self.kind}_occluded"])
        lib.rtcCommitGeometry(geom)
        device.check(f"setting up {what} ({self.kind} user geometry)")
        return geom


def _finite(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value, np.float64)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected finite numbers of shape {shape}, got {value!r}")
    return a


def _padded(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box grown by a few float32 ulps, so that rounding never cuts off the surface."""
    pad = 1e-6 * (np.abs(lo) + np.abs(hi) + (hi - lo)) + 1e-30
    return lo - pad, hi + pad


def _block(kind: str, **parts: Any) -> UserShape:
    """The shape whose block holds ``parts`` where ``USER_BLOCK`` places them, zeros elsewhere."""
    assert kind in USER_KINDS, kind
    block = np.zeros(USER_BLOCK_DOUBLES)
    for name, value in parts.items():
        first, size = USER_BLOCK[name]
        block[first:first + size] = value
    return UserShape(kind, block)


def sphere(center: Any, radius: float) -> UserShape:
    """The sphere of ``radius`` around ``center`` (world space)."""
    c = _finite("center", center, (3,))
    r = float(radius)
    if not (np.isfinite(r) and r > 0):
        raise ValueError(f"radius: expected a positive number, got {radius!r}")
    lower, upper = _padded(c - r, c + r)
    return _block("sphere", center=c, radius=r, lower=lower, upper=upper)


def disk(to_world: Any) -> UserShape:
    """The unit disk at z = 0 of object space, placed by the affine 4x4 ``to_world``."""
    m = _finite("to_world", to_world, (4, 4))
    lin = m[:3, :3]
    if abs(np.linalg.det(lin)) < 1e-30:
        raise ValueError("to_world: the transform is singular")
    inv = np.linalg.inv(m)
    n = np.linalg.inv(lin).T @ np.array([0.0, 0.0, 1.0])
    # the disk's extent along each world axis: |row of the linear part restricted to x, y|
    half = np.sqrt(lin[:, 0] ** 2 + lin[:, 1] ** 2)
    lower, upper = _padded(m[:3, 3] - half, m[:3, 3] + half)
    return _block("disk", to_object=inv[:3, :4].reshape(-1), normal=n / np.linalg.norm(n),
                  lower=lower, upper=upper)


_sdf_kernel: list[Any] = []  # the compiled module of the SDF grids' kernel, once loaded
_sdf_lock = threading.Lock()


def _sdfgrid_kernel() -> tuple[Any, int]:
    """The module of stdlib/render/sdfgrid_kernel.rdsl (scalar, mono) and the address of its
    ``rdsl_sdfgrid_intersect``."""
    with _sdf_lock:
        if not _sdf_kernel:
            from .api import jit
            from ..dsl.imports import STDLIB

            mod = jit(STDLIB / "render" / "sdfgrid_kernel.rdsl", target="scalar",
                      variant="mono")
            fn = mod["sdfgrid_intersect"]._fn
            _sdf_kernel.extend([mod, ctypes.cast(fn, ctypes.c_void_p).value])
        return _sdf_kernel[0], _sdf_kernel[1]


def sdfgrid(record: np.ndarray, to_world: Any) -> UserShape:
    """The SDF grid of ``record`` (float32, stdlib/render/sdfgrid.rdsl's layout), the unit
    cube placed by the affine 4x4 ``to_world``."""
    m = _finite("to_world", to_world, (4, 4))
    rec = np.ascontiguousarray(record, np.float32)
    corners = np.array([[(i >> a) & 1 for a in range(3)] + [1] for i in range(8)], np.float64)
    world = (corners @ m.T)[:, :3]
    lower, upper = _padded(world.min(axis=0), world.max(axis=0))
    mod, kernel = _sdfgrid_kernel()
    shape = _block("sdfgrid", lower=lower, upper=upper)
    shape.block[USER_BLOCK["kernel"][0]:USER_BLOCK["record"][0] + 1] = \
        np.array([kernel, rec.ctypes.data], np.int64).view(np.float64)
    shape.keep = (rec, mod)
    return shape


__all__ = ["UserShape", "disk", "sdfgrid", "sphere"]
