"""Mitsuba's curve shapes as Embree 4 round curves (``RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE``,
``RTC_GEOMETRY_TYPE_ROUND_BSPLINE_CURVE``), set up as Mitsuba 3's ``embree_geometry`` does:
a vertex buffer of float4 (x, y, z, radius) and an index buffer of each segment's first
control point.  Embree reports a hit's segment as ``primID`` and the curve parameter along
it as ``u``; stdlib/render/geometry.rdsl derives the rest of the surface from those.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from .embree import EmbreeDevice

GEOMETRY_TYPES = {"linearcurve": 16, "bsplinecurve": 32}  # RTC_GEOMETRY_TYPE_ROUND_*_CURVE
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT, _FORMAT_FLOAT4 = 0x5001, 0x9004


_SIGNATURES = {name: (None, [ctypes.c_void_p, ctypes.c_void_p])
               for name in ("rtcSetGeometryIntersectFilterFunction",
                            "rtcSetGeometryOccludedFilterFunction")}


def _declare(lib: ctypes.CDLL) -> None:
    for name, (res, args) in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args


class EmbreeCurves:
    """A curve shape for :class:`rdsl.runtime.embree.EmbreeScene` (which accepts these among
    its meshes): ``points`` (N, 4) x, y, z, radius in world space, ``segments`` the index of
    each segment's first control point."""

    def __init__(self, kind: str, points: Any, segments: Any) -> None:
        if kind not in GEOMETRY_TYPES:
            raise ValueError(f"kind: expected one of {', '.join(GEOMETRY_TYPES)}, got {kind!r}")
        self.kind = kind
        self.points = np.ascontiguousarray(points, np.float32)
        self.segments = np.ascontiguousarray(segments, np.uint32)
        span = 2 if kind == "linearcurve" else 4
        if self.points.ndim != 2 or self.points.shape[1] != 4:
            raise ValueError(f"points: expected shape (N, 4), got {self.points.shape}")
        if len(self.segments) == 0 or int(self.segments.max()) + span > len(self.points):
            raise ValueError("segments: a segment's control points are out of range")

    def new_geometry(self, device: EmbreeDevice, what: str) -> int:
        """A committed curve geometry (the caller attaches and releases it)."""
        lib = device.lib
        geom = lib.rtcNewGeometry(device.handle, GEOMETRY_TYPES[self.kind])
        device.check(f"rtcNewGeometry ({what}, {self.kind})")
        vb = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT4, 16,
                                         len(self.points))
        ib = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT, 4,
                                         len(self.segments))
        device.check(f"rtcSetNewGeometryBuffer ({what}, {self.kind})")
        ctypes.memmove(vb, self.points.ctypes.data, self.points.nbytes)
        ctypes.memmove(ib, self.segments.ctypes.data, self.segments.nbytes)
        # back faces culled, as in Mitsuba (its Embree is built with
        # EMBREE_BACKFACE_CULLING_CURVES): an open B-spline end shows no inner wall, and a
        # ray leaving the inside of a tube passes out of it
        from ..compiler.backends.llvm_shapes import callback_addresses

        cull = callback_addresses()["backface_filter"]
        _declare(lib)
        lib.rtcSetGeometryIntersectFilterFunction(geom, cull)
        lib.rtcSetGeometryOccludedFilterFunction(geom, cull)
        lib.rtcCommitGeometry(geom)
        device.check(f"setting up {what} ({self.kind})")
        return geom


__all__ = ["GEOMETRY_TYPES", "EmbreeCurves"]
