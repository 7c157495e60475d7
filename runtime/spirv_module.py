"""Loading a SPIR-V build (``<stem>.spv`` + ``<stem>.json``, see
``compiler/backends/spirv_build.py``) as an :class:`rdsl.Module` whose kernels run on Vulkan.

The kernels are the runtime's ordinary :class:`~rdsl.runtime.kernel.Kernel` s: they convert
arrays and call entry points with the C ABI (``base.c_params``: pointers, byte strides, the
mask).  Here the "library" behind those entry points is :class:`ShaderKernel`, which reads
the strided arrays the pointers describe, packs them into the shader's storage buffers,
dispatches one invocation per element and writes the results of the active elements back,
so strided layouts, masks, ``out=`` and structured parameters work as on the CPU targets.
"""

from __future__ import annotations

import ctypes
import json
import struct
import threading
from pathlib import Path
from typing import Any

import numpy as np

from .api import Module
from .kernel import Kernel
from .vulkan import Device, Pipeline, VulkanUnavailable

# element types in the shader's buffers (bools are 32-bit there) and in the caller's memory
MEM_NP = {"f32": np.dtype(np.float32), "i32": np.dtype(np.int32),
          "u32": np.dtype(np.uint32), "u64": np.dtype(np.uint64), "bool": np.dtype(np.uint32)}
HOST_NP = {**MEM_NP, "bool": np.dtype(np.uint8)}
_PACK = {"f32": "<f", "i32": "<i", "u32": "<I", "u64": "<Q", "bool": "<I"}


def strided(addr: int, stride: int, n: int, dtype: np.dtype) -> np.ndarray:
    """The ``n`` elements at ``addr + i * stride`` as a (writeable) numpy view."""
    if n <= 0 or not addr:
        return np.empty(0, dtype)
    lo = addr + min(0, stride * (n - 1))
    span = abs(stride) * (n - 1) + dtype.itemsize
    raw = (ctypes.c_char * span).from_address(lo)
    return np.ndarray((n,), dtype, buffer=raw, offset=addr - lo, strides=(stride,))


class ShaderKernel:
    """One kernel's shader behind its C-ABI entry points (``__call__``: ``n`` first;
    :meth:`range`: ``begin, end`` first)."""

    def __init__(self, info: dict[str, Any], spv: bytes) -> None:
        self.info = info
        self.shader = info["shader"]
        self.spv = spv
        self.pipe: Pipeline | None = None
        self.lock = threading.Lock()
        self.buffers: dict[int, np.ndarray] = {}  # address -> buffer array of this call
        # argtypes/restype are set by Kernel (as on a ctypes function); unused here
        self.argtypes: Any = None
        self.restype: Any = None

    def pipeline(self) -> Pipeline:
        if self.pipe is None:
            dev = Device.get()
            if self.shader["int64"] and not dev.int64:
                raise VulkanUnavailable(f"kernel `{self.info['name']}` uses 64-bit integers "
                                        f"(UInt64); the Vulkan device `{dev.name}` lacks "
                                        "shaderInt64")
            self.pipe = Pipeline(dev, dev.shader(self.spv), self.shader["entry"],
                                 self.shader["bindings"])
        return self.pipe

    def __call__(self, n: int, *flat: Any) -> None:
        self.range(0, n, *flat)

    def range(self, begin: int, end: int, *flat: Any) -> None:
        """Run elements [begin, end) of the arrays ``flat`` (the C ABI's arguments)."""
        values: dict[str, Any] = {}
        k = 0
        for a in self.info["args"]:
            v = flat[k]
            k += 1
            if a["strided"]:
                v = strided(v or 0, flat[k], end, HOST_NP[a["dtype"]])[begin:]
                k += 1
            elif a["kind"] == "buffer":
                v = self.buffers[v]
            values[a["name"]] = v
        mask = strided(flat[k], flat[k + 1], end, HOST_NP["bool"])[begin:] \
            if flat[k] else None
        with self.lock:
            pipe = self.pipeline()
            step = self.chunk(values, pipe.dev.max_range)
            for lo in range(0, end - begin, step):
                hi = min(lo + step, end - begin)
                part = {a["name"]: values[a["name"]][lo:hi] if a["strided"] else
                        values[a["name"]] for a in self.info["args"]}
                self.run(hi - lo, part, None if mask is None else mask[lo:hi])

    def chunk(self, values: dict[str, Any], limit: int) -> int:
        """Elements per dispatch such that no pool outgrows ``limit`` bytes."""
        fixed: dict[str, int] = {}
        per: dict[str, int] = {"U": 4}
        for a in self.shader["arrays"]:
            size = MEM_NP[a["dtype"]].itemsize
            if a["kind"] == "buffer":
                fixed[a["pool"]] = fixed.get(a["pool"], 0) + values[a["arg"]].size * size
            elif a["kind"] != "mask":
                per[a["pool"]] = per.get(a["pool"], 0) + size
        room = min((limit - fixed.get(p, 0)) // b for p, b in per.items())
        if room < 1:
            raise VulkanUnavailable(f"kernel `{self.info['name']}`: its buffers exceed the "
                                    f"device's storage-buffer range ({limit} bytes)")
        return max(1, min(room, 1 << 24))

    # long: one straight sequence (layout, parameters, pools, dispatch, results)
    def run(self, n: int, values: dict[str, Any], mask: np.ndarray | None) -> None:
        """Upload, dispatch ``n`` invocations, write back the outputs of active elements
        (into the arrays of ``values``) and the buffers."""
        if n <= 0:
            return
        pipe = self.pipeline()
        params = bytearray(self.shader["params_size"])
        struct.pack_into("<II", params, 0, n, int(mask is not None))
        sizes = dict.fromkeys(_POOL_NP, 0)
        spans = []
        for a in self.shader["arrays"]:
            count = values[a["arg"]].size if a["kind"] == "buffer" else \
                (0 if mask is None else n) if a["kind"] == "mask" else n
            struct.pack_into("<I", params, a["offset"], sizes[a["pool"]])
            spans.append((a, sizes[a["pool"]], count))
            sizes[a["pool"]] += count
        for u in self.shader["uniforms"]:
            v = values[u["name"]]
            v = int(bool(v)) if u["dtype"] == "bool" else v
            struct.pack_into(_PACK[u["dtype"]], params, u["offset"],
                             MEM_NP[u["dtype"]].type(v).item())
        pipe.upload(0, bytes(params))
        pools = {p: pipe.room(k, sizes[p] * _POOL_NP[p].itemsize).view(_POOL_NP[p])
                 for p, k in _POOL_BINDING.items()}
        for a, off, count in spans:
            if a["kind"] in ("varying", "buffer"):
                pools[a["pool"]][off:off + count] = np.asarray(values[a["arg"]]).reshape(-1)
            elif a["kind"] == "mask" and mask is not None:
                pools["U"][off:off + count] = mask
        pipe.dispatch(n, self.shader["local_size"])
        active = None if mask is None else mask != 0
        for a, off, count in spans:
            got = pools[a["pool"]][off:off + count]
            if a["kind"] == "output":
                dest = values[a["arg"]]
                dest[...] = got if active is None else np.where(active, got, dest)
            elif a["kind"] == "buffer" and values[a["arg"]].flags.writeable and count:
                buf = values[a["arg"]]
                buf[...] = got.reshape(buf.shape)


_POOL_NP = {"F": np.dtype(np.float32), "I": np.dtype(np.int32), "U": np.dtype(np.uint32),
            "L": np.dtype(np.uint64)}
_POOL_BINDING = {"F": 1, "I": 2, "U": 3, "L": 4}


class ShaderLibrary:
    """What :class:`Kernel` takes for a ``ctypes.CDLL``: entry points by symbol."""

    def __init__(self, manifest: dict[str, Any], spv: bytes) -> None:
        self.entries: dict[str, ShaderKernel] = {}
        for info in manifest["kernels"]:
            sk = ShaderKernel(info, spv)
            self.entries[info["symbol"]] = sk
            self.entries[info["range_symbol"]] = _Range(sk)

    def __getattr__(self, name: str) -> Any:
        try:
            return self.__dict__["entries"][name]
        except KeyError:
            raise AttributeError(name) from None


class _Range:
    def __init__(self, sk: ShaderKernel) -> None:
        self.sk = sk

    def __call__(self, begin: int, end: int, *flat: Any) -> None:
        self.sk.range(begin, end, *flat)


class SpirvKernel(Kernel):
    """A :class:`Kernel` whose entry points are a shader's: one call is one dispatch (not
    split over the CPU thread pool)."""

    def _buffer(self, p: dict[str, Any], value: Any) -> np.ndarray:
        arr = super()._buffer(p, value)
        self._fn.buffers[arr.ctypes.data] = arr
        return arr

    def _run(self, n: int, flat: list[Any], threads: int | None) -> list:
        try:
            if n > 0:
                self._fn(n, *flat)
        finally:
            self._fn.buffers.clear()
        return []


class SpirvModule(Module):
    """A loaded SPIR-V build."""

    def __init__(self, manifest: dict[str, Any], lib: ShaderLibrary, path: Path,
                 **kwargs: Any) -> None:
        super().__init__(manifest, lib, path, **kwargs)  # type: ignore[arg-type]
        self.kernels = {k["name"]: SpirvKernel(self, k, lib)  # type: ignore[arg-type]
                        for k in manifest["kernels"]}

    @property
    def traces_rays(self) -> bool:
        return False  # the spirv target rejects ray queries at compile time


def load_spirv(man: Path, spv: Path, manifest: dict[str, Any] | None = None,
               **kwargs: Any) -> SpirvModule:
    """Load ``<stem>.json`` and ``<stem>.spv``; the Vulkan device is opened at the first
    kernel call."""
    manifest = manifest if manifest is not None else json.loads(man.read_text())
    lib = ShaderLibrary(manifest, spv.read_bytes())
    return SpirvModule(manifest, lib, spv, **kwargs)
