"""Embree instancing: a shapegroup's meshes as one Embree scene of their own
(:class:`EmbreeGroup`, built once) and each instance of it as an ``RTC_GEOMETRY_TYPE_INSTANCE``
geometry of the top-level scene with its own transform (:class:`EmbreeInstance`), so that
10^4 instances of a mesh cost memory for one.

An instance takes as many geometry IDs of the top-level scene as its group has meshes
(``slots``): :class:`~rdsl.runtime.embree.EmbreeScene` attaches it at the first, and the ray
queries report a hit on mesh k of the group as that ID + k (``instID + geomID``:
compiler/backends/llvm_rays.py), the G entry of that mesh of that instance.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import Any

import numpy as np

from .embree import EmbreeDevice, EmbreeScene

GEOMETRY_TYPE_INSTANCE = 121  # RTC_GEOMETRY_TYPE_INSTANCE
FORMAT_FLOAT3X4_ROW_MAJOR = 0x9134

_P = ctypes.c_void_p
_SIGNATURES: dict[str, tuple[Any, list[Any]]] = {
    "rtcSetGeometryInstancedScene": (None, [_P, _P]),
    "rtcSetGeometryTransform": (None, [_P, ctypes.c_uint, ctypes.c_int, _P]),
}


def _declare(lib: ctypes.CDLL) -> ctypes.CDLL:
    for name, (res, args) in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


class EmbreeGroup:
    """A shapegroup's meshes, ``(vertices, faces)`` each, as an Embree scene built on first
    use and shared by every instance of it."""

    def __init__(self, meshes: Sequence[Any]) -> None:
        self.meshes = list(meshes)
        self.scene: EmbreeScene | None = None

    def handle(self, device: EmbreeDevice) -> int:
        """The group's committed ``RTCScene`` on ``device``."""
        if self.scene is None or self.scene.device is not device:
            self.scene = EmbreeScene(self.meshes, quality="high", device=device)
        return self.scene.handle

    def close(self) -> None:
        if self.scene is not None:
            self.scene.close()
            self.scene = None


class EmbreeInstance:
    """One instance of an :class:`EmbreeGroup`, placed by the 4x4 affine ``to_world``."""

    def __init__(self, group: EmbreeGroup, to_world: Any) -> None:
        m = np.asarray(to_world, np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f"to_world: expected a finite 4x4 matrix, got {to_world!r}")
        self.group = group
        self.xfm = np.ascontiguousarray(m[:3, :4], np.float32)  # kept alive: Embree copies it
        self.slots = len(group.meshes)

    def new_geometry(self, device: EmbreeDevice, what: str) -> int:
        """A committed instance geometry (the caller attaches and releases it)."""
        lib = _declare(device.lib)
        scene = self.group.handle(device)
        geom = lib.rtcNewGeometry(device.handle, GEOMETRY_TYPE_INSTANCE)
        device.check(f"rtcNewGeometry ({what}, instance)")
        lib.rtcSetGeometryInstancedScene(geom, scene)
        lib.rtcSetGeometryTransform(geom, 0, FORMAT_FLOAT3X4_ROW_MAJOR, self.xfm.ctypes.data)
        lib.rtcCommitGeometry(geom)
        device.check(f"setting up {what} (instance)")
        return geom


__all__ = ["EmbreeGroup", "EmbreeInstance"]
