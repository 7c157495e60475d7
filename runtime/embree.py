"""Embree 4 ray tracing from Python: the library, its device, and a scene of triangle meshes.

The renderer's compiled kernels call ``rtcIntersectN``/``rtcOccludedN`` directly (the
backend emits those calls: ``compiler/backends/embree_llvm.py``); this module gives them a
scene to trace, through ctypes:

- :func:`load_embree` finds ``libembree4`` inside the ``embreex`` wheel and declares the part
  of the C API rdsl uses;
- :func:`symbol_addresses` and :func:`bind_llvm_symbols` hand the query functions to an
  in-process JIT (``cc`` links a ``.so`` with :func:`rdsl.core.embree_abi.link_args`);
- :class:`EmbreeScene` builds a scene from triangle meshes (and the analytic shapes of
  ``embree_user.py``) and traces numpy batches of rays.  That path loops in Python over
  16-ray packets: it is for tests and tooling, not rendering.

The packet layouts and constants it shares with the backend are in
:mod:`rdsl.core.embree_abi`.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.embree_abi import (
    QUERIES,
    QUERY_FUNCTIONS,
    RTC_INVALID_GEOMETRY_ID,
    UINT_FIELDS,
    WIDTHS,
    EmbreeError,
    PacketLayout,
    check_width,
    embree_library_path,
)

# enum values from embree4/rtcore_*.h
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_DEVICE_PROPERTY_VERSION = 0
BUILD_QUALITY = {"low": 0, "medium": 1, "high": 2}
SCENE_FLAGS = {"dynamic": 1, "compact": 2, "robust": 4}
ERROR_NAMES = {0: "RTC_ERROR_NONE", 1: "RTC_ERROR_UNKNOWN", 2: "RTC_ERROR_INVALID_ARGUMENT",
               3: "RTC_ERROR_INVALID_OPERATION", 4: "RTC_ERROR_OUT_OF_MEMORY",
               5: "RTC_ERROR_UNSUPPORTED_CPU", 6: "RTC_ERROR_CANCELLED"}


# --------------------------------------------------------------------------- library

_lib: ctypes.CDLL | None = None
_lib_lock = threading.RLock()
_P = ctypes.c_void_p
_ERROR_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p)

_SIGNATURES: dict[str, tuple[Any, list[Any]]] = {
    "rtcNewDevice": (_P, [ctypes.c_char_p]),
    "rtcReleaseDevice": (None, [_P]),
    "rtcGetDeviceError": (ctypes.c_int, [_P]),
    "rtcGetDeviceProperty": (ctypes.c_ssize_t, [_P, ctypes.c_int]),
    "rtcSetDeviceErrorFunction": (None, [_P, _ERROR_FN, _P]),
    "rtcNewScene": (_P, [_P]),
    "rtcCommitScene": (None, [_P]),
    "rtcReleaseScene": (None, [_P]),
    "rtcSetSceneBuildQuality": (None, [_P, ctypes.c_int]),
    "rtcSetSceneFlags": (None, [_P, ctypes.c_int]),
    "rtcNewGeometry": (_P, [_P, ctypes.c_int]),
    "rtcSetNewGeometryBuffer": (_P, [_P, ctypes.c_int, ctypes.c_uint, ctypes.c_int,
                                     ctypes.c_size_t, ctypes.c_size_t]),
    "rtcSetGeometryBuildQuality": (None, [_P, ctypes.c_int]),
    "rtcCommitGeometry": (None, [_P]),
    "rtcAttachGeometry": (ctypes.c_uint, [_P, _P]),
    "rtcAttachGeometryByID": (None, [_P, _P, ctypes.c_uint]),
    "rtcReleaseGeometry": (None, [_P]),
    # rtcIntersect1(scene, rayhit, args); rtcIntersectN(valid, scene, rayhit, args)
    **{f"rtc{q}1": (None, [_P, _P, _P]) for q in QUERIES},
    **{f"rtc{q}{w}": (None, [_P, _P, _P, _P]) for q in QUERIES for w in WIDTHS[1:]},
}


def load_embree() -> ctypes.CDLL:
    """Load ``libembree4`` from the ``embreex`` wheel (once) with its API declared.

    The library is loaded RTLD_GLOBAL, so that JIT-compiled code can resolve its symbols."""
    global _lib
    with _lib_lock:
        if _lib is None:
            path = embree_library_path()
            try:
                lib = ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
            except OSError as e:
                raise EmbreeError(f"cannot load Embree from {path}: {e}") from None
            for name, (res, args) in _SIGNATURES.items():
                fn = getattr(lib, name)
                fn.restype, fn.argtypes = res, args
            _lib = lib
        return _lib


def symbol_addresses() -> dict[str, int]:
    """Addresses of ``rtcIntersect{1,4,8,16}`` and ``rtcOccluded{1,4,8,16}``."""
    lib = load_embree()
    return {name: ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
            for name in QUERY_FUNCTIONS}


def bind_llvm_symbols() -> dict[str, int]:
    """Make the query functions resolvable by llvmlite's in-process JIT (MCJIT or LLJIT)."""
    import llvmlite.binding as llvm

    addrs = symbol_addresses()
    for name, addr in addrs.items():
        llvm.add_symbol(name, addr)
    return addrs


# --------------------------------------------------------------------------- device


class EmbreeDevice:
    """An ``RTCDevice`` whose errors become :class:`EmbreeError` exceptions.

    Embree reports errors through a callback, which cannot raise through C; the callback
    records the error and :meth:`check`, called after each API call, raises it."""

    def __init__(self, config: str = "") -> None:
        self.lib = load_embree()
        self._errors: list[tuple[int, str]] = []
        self._callback = _ERROR_FN(self._on_error)  # kept alive as long as the device
        handle = self.lib.rtcNewDevice(config.encode())
        if not handle:
            code = self.lib.rtcGetDeviceError(None)
            raise EmbreeError(f"rtcNewDevice({config!r}) failed: "
                              f"{ERROR_NAMES.get(code, code)}")
        self.handle: int | None = handle
        self.lib.rtcSetDeviceErrorFunction(handle, self._callback, None)
        self.version = int(self.lib.rtcGetDeviceProperty(handle, _DEVICE_PROPERTY_VERSION))
        if self.version // 10000 != 4:
            self.close()
            raise EmbreeError(f"rdsl needs Embree 4, but the library is version "
                              f"{self.version // 10000}.{self.version // 100 % 100}")

    def _on_error(self, _user: Any, code: int, msg: bytes | None) -> None:
        self._errors.append((code, (msg or b"").decode(errors="replace")))

    def check(self, what: str) -> None:
        """Raise the error that Embree reported since the last check, if any."""
        code = self.lib.rtcGetDeviceError(self.handle) if self.handle else 0
        if self._errors or code:
            err, msg = self._errors[0] if self._errors else (code, "")
            self._errors.clear()
            raise EmbreeError(f"{what} failed: {ERROR_NAMES.get(err, err)}"
                              + (f": {msg}" if msg else ""))

    def close(self) -> None:
        """Release the device (scenes keep it alive until they are released)."""
        if self.handle:
            self.lib.rtcReleaseDevice(self.handle)
            self.handle = None

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # at interpreter shutdown
            self.close()


_default_device: EmbreeDevice | None = None


# Embree's device configuration for the process-wide device (``rtcNewDevice``'s string, for
# example ``isa=avx2``: Embree's AVX2 kernels on an AVX-512 CPU, as the bit-identical test
# uses to reproduce an AVX2-only host's images; ``verbose=1``)
CONFIG_ENV = "RDSL_EMBREE_CONFIG"


def default_device() -> EmbreeDevice:
    """The process-wide device (Embree devices own a thread pool: share one), configured by
    ``$RDSL_EMBREE_CONFIG`` when set."""
    global _default_device
    with _lib_lock:
        if _default_device is None:
            _default_device = EmbreeDevice(os.environ.get(CONFIG_ENV, ""))
        return _default_device


# --------------------------------------------------------------------------- validation


def _float_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    a = np.asarray(value)
    if a.dtype.kind not in "fiu" or a.dtype == np.bool_:
        raise ValueError(f"{name}: expected real numbers, got dtype {a.dtype}")
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or infinite values (or overflows float32)")
    return a


def _check_mesh(i: int, mesh: Any) -> tuple[np.ndarray, np.ndarray]:
    try:
        vertices, faces = mesh
    except (TypeError, ValueError):
        raise ValueError(f"meshes[{i}]: expected a (vertices, faces) pair") from None
    v = _float_array(f"meshes[{i}].vertices", vertices, (None, 3))
    f = np.asarray(faces)
    name = f"meshes[{i}].faces"
    if f.dtype.kind not in "iu":
        raise ValueError(f"{name}: expected integer vertex indices, got dtype {f.dtype}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (M, 3), got {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        bad = int(f.min()) if f.min() < 0 else int(f.max())
        raise ValueError(f"{name}: vertex index {bad} is out of range for {len(v)} vertices")
    if len(f) == 0:
        raise ValueError(f"{name}: the mesh has no triangles")
    return v, np.ascontiguousarray(f, dtype=np.uint32)


def _aligned_words(n_words: int, align: int) -> np.ndarray:
    """A zeroed uint32 array of ``n_words`` whose data is aligned to ``align`` bytes."""
    raw = np.zeros(4 * n_words + align, dtype=np.uint8)
    skip = (-raw.ctypes.data) % align
    return raw[skip:skip + 4 * n_words].view(np.uint32)


# --------------------------------------------------------------------------- scene


class EmbreeScene:
    """A committed Embree scene of triangle meshes; mesh i has geometry ID i (an instance of
    runtime/embree_instance.py takes one ID per mesh of its group).

    ``meshes`` is a sequence of ``(vertices, faces)``: vertices (N, 3) real numbers (stored as
    float32), faces (M, 3) integer indices into the vertices. ``quality`` is the scene's BVH
    build quality (low, medium, high); ``robust`` asks Embree for robust (slower) traversal.
    At quality ``low`` Embree builds two levels: a BVH per mesh, of ``mesh_quality``, under a
    BVH over the meshes.  Scenes made of a few large shapes (the Cornell box's walls) trace
    faster that way than through one BVH over all their triangles, whose leaves mix walls.

    Compiled kernels take :attr:`handle` (the ``RTCScene``); keep this object alive while
    they run. :meth:`close` (or leaving a ``with`` block) releases the scene."""

    def __init__(self, meshes: Sequence[Any], *, quality: str = "medium",
                 mesh_quality: str = "medium", robust: bool = False,
                 device: EmbreeDevice | None = None) -> None:
        for what, q in (("quality", quality), ("mesh_quality", mesh_quality)):
            if q not in BUILD_QUALITY:
                raise ValueError(f"{what}: expected one of {', '.join(BUILD_QUALITY)}, "
                                 f"got {q!r}")
        if isinstance(meshes, tuple) and len(meshes) == 2 and isinstance(meshes[0], np.ndarray):
            meshes = [meshes]  # a single (vertices, faces) pair
        # an analytic shape (runtime/embree_user.py) is a user geometry, not a mesh
        checked = [m if hasattr(m, "new_geometry") else _check_mesh(i, m)
                   for i, m in enumerate(meshes)]
        self.device = device or default_device()
        self.lib = lib = self.device.lib
        self.handle: int | None = None
        self.user_shapes = [m for m in checked if hasattr(m, "new_geometry")]  # kept alive
        self.counts = [(0, 0) if hasattr(m, "new_geometry") else (len(m[0]), len(m[1]))
                       for m in checked]
        scene = lib.rtcNewScene(self.device.handle)
        self.device.check("rtcNewScene")
        self.handle = scene
        lib.rtcSetSceneBuildQuality(scene, BUILD_QUALITY[quality])
        lib.rtcSetSceneFlags(scene, SCENE_FLAGS["robust"] if robust else 0)
        geom_id = 0  # an instance (runtime/embree_instance.py) takes one ID per group mesh
        for i, item in enumerate(checked):
            if hasattr(item, "new_geometry"):  # a user geometry or an instance, committed
                geom = item.new_geometry(self.device, f"meshes[{i}]")
                try:
                    lib.rtcAttachGeometryByID(scene, geom, geom_id)
                    self.device.check(f"attaching meshes[{i}]")
                finally:
                    lib.rtcReleaseGeometry(geom)
                geom_id += getattr(item, "slots", 1)
                continue
            v, f = item
            geom = lib.rtcNewGeometry(self.device.handle, _GEOMETRY_TYPE_TRIANGLE)
            self.device.check(f"rtcNewGeometry (meshes[{i}])")
            try:
                vb = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3,
                                                 12, len(v))
                ib = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3,
                                                 12, len(f))
                self.device.check(f"rtcSetNewGeometryBuffer (meshes[{i}])")
                ctypes.memmove(vb, v.ctypes.data, v.nbytes)
                ctypes.memmove(ib, f.ctypes.data, f.nbytes)
                lib.rtcSetGeometryBuildQuality(geom, BUILD_QUALITY[mesh_quality])
                lib.rtcCommitGeometry(geom)
                lib.rtcAttachGeometryByID(scene, geom, geom_id)
                self.device.check(f"attaching meshes[{i}]")
            finally:
                lib.rtcReleaseGeometry(geom)  # the scene holds its own reference
            geom_id += 1
        lib.rtcCommitScene(scene)
        self.device.check("rtcCommitScene")

    # lifetime -------------------------------------------------------------

    def close(self) -> None:
        """Release the scene. Compiled code must not use :attr:`handle` afterwards."""
        if self.handle:
            self.lib.rtcReleaseScene(self.handle)
            self.handle = None

    def __enter__(self) -> EmbreeScene:  # noqa: PYI034 (typing.Self needs 3.11)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):  # at interpreter shutdown
            self.close()

    def __repr__(self) -> str:
        tris = sum(m for _, m in self.counts)
        state = "closed" if not self.handle else f"handle=0x{self.handle:x}"
        return f"EmbreeScene({len(self.counts)} meshes, {tris} triangles, {state})"

    def symbol_addresses(self) -> dict[str, int]:
        """Addresses of the query functions, for binding into a JIT (see module docs)."""
        return symbol_addresses()

    # queries --------------------------------------------------------------

    def _rays(self, origins: Any, dirs: Any, tmax: Any, tmin: Any
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        if not self.handle:
            raise EmbreeError("the scene was closed")
        o = _float_array("origins", origins, (None, 3))
        d = _float_array("dirs", dirs, (None, 3))
        n = len(o)
        if len(d) != n:
            raise ValueError(f"dirs: expected {n} directions (one per origin), got {len(d)}")
        ends = []
        for name, val in (("tmax", tmax), ("tmin", tmin)):
            a = np.asarray(val, dtype=np.float32)
            if a.ndim > 1 or (a.ndim == 1 and len(a) != n):
                raise ValueError(f"{name}: expected a number or an array of {n}, got shape "
                                 f"{a.shape}")
            if np.any(np.isnan(a)):
                raise ValueError(f"{name}: contains NaN")
            ends.append(np.broadcast_to(a, (n,)))
        return o, d, ends[0], ends[1]

    def _packets(self, lay: PacketLayout, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
                 tmin: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        n, w = len(o), lay.width
        packets = max(1, -(-n // w))
        buf = _aligned_words(packets * lay.words, lay.align).reshape(packets, lay.words)
        f = buf.view(np.float32)

        def put(field: str, values: np.ndarray, pad: float = 0) -> None:
            col = np.full(packets * w, pad, dtype=values.dtype)
            col[:n] = values
            view = buf if field in UINT_FIELDS else f
            off = lay.offset(field)
            view[:, off:off + w] = col.reshape(packets, w)

        for k, axis in enumerate("xyz"):
            put(f"org_{axis}", o[:, k])
            put(f"dir_{axis}", d[:, k], 1.0)
        put("tnear", tmin)
        put("tfar", tmax)
        buf[:, lay.offset("mask"):lay.offset("mask") + w] = 0xFFFFFFFF
        put("id", np.arange(n, dtype=np.uint32))
        if lay.with_hit:
            for field in ("geomID", "primID", "instID", "instPrimID"):
                buf[:, lay.offset(field):lay.offset(field) + w] = RTC_INVALID_GEOMETRY_ID
        valid = _aligned_words(packets * w, lay.align).reshape(packets, w).view(np.int32)
        valid.reshape(-1)[:n] = -1
        return buf, valid, packets

    def _run(self, query: str, lay: PacketLayout, buf: np.ndarray, valid: np.ndarray,
             packets: int) -> None:
        fn = getattr(self.lib, f"rtc{query}{lay.width}")
        scene, base, stride = self.handle, buf.ctypes.data, lay.nbytes
        if lay.width == 1:
            for p in range(packets):
                fn(scene, base + p * stride, None)
        else:
            vbase, vstride = valid.ctypes.data, 4 * lay.width
            for p in range(packets):
                fn(vbase + p * vstride, scene, base + p * stride, None)
        self.device.check(f"rtc{query}{lay.width}")

    def intersect(self, origins: Any, dirs: Any, tmax: Any = np.inf, *, tmin: Any = 0.0,
                  width: int = 16) -> dict[str, np.ndarray]:
        """Closest hits of a batch of rays ``origins + t * dirs``, ``tmin <= t <= tmax``.

        Returns arrays of length N: ``hit`` (bool), ``t`` (inf on a miss), ``prim_id`` and
        ``geom_id`` (int64, -1 on a miss), ``u``, ``v`` (barycentrics of vertices 1 and 2)
        and ``ng`` (N, 3), Embree's unnormalized geometric normal. ``width`` picks the
        ``rtcIntersect`` packet width."""
        lay = PacketLayout(check_width(width))
        o, d, tmax_a, tmin_a = self._rays(origins, dirs, tmax, tmin)
        n = len(o)
        buf, valid, packets = self._packets(lay, o, d, tmax_a, tmin_a)
        if n:
            self._run("Intersect", lay, buf, valid, packets)
        f = buf.view(np.float32)

        def get(field: str, view: np.ndarray) -> np.ndarray:
            off = lay.offset(field)
            return view[:, off:off + lay.width].reshape(-1)[:n]

        geom = get("geomID", buf)
        hit = geom != RTC_INVALID_GEOMETRY_ID
        t = np.where(hit, get("tfar", f), np.float32(np.inf)).astype(np.float32)
        ids = {k: np.where(hit, get(field, buf).astype(np.int64), -1)
               for k, field in (("prim_id", "primID"), ("geom_id", "geomID"))}
        ng = np.stack([get(f"Ng_{a}", f) for a in "xyz"], axis=1)
        return {"hit": hit, "t": t, **ids, "u": get("u", f).copy(), "v": get("v", f).copy(),
                "ng": np.where(hit[:, None], ng, np.float32(0.0))}

    def occluded(self, origins: Any, dirs: Any, tmax: Any = np.inf, *, tmin: Any = 0.0,
                 width: int = 16) -> np.ndarray:
        """Whether anything lies on each ray segment ``tmin <= t <= tmax`` (bool array)."""
        lay = PacketLayout(check_width(width), with_hit=False)
        o, d, tmax_a, tmin_a = self._rays(origins, dirs, tmax, tmin)
        n = len(o)
        buf, valid, packets = self._packets(lay, o, d, tmax_a, tmin_a)
        if n:
            self._run("Occluded", lay, buf, valid, packets)
        off = lay.offset("tfar")
        tfar = buf.view(np.float32)[:, off:off + lay.width].reshape(-1)[:n]
        return tfar == -np.inf  # Embree sets tfar to -inf on an occluded ray


__all__ = [
    "BUILD_QUALITY", "EmbreeDevice", "EmbreeError", "EmbreeScene", "bind_llvm_symbols",
    "default_device", "load_embree", "symbol_addresses",
]
