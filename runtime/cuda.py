"""Running PTX kernels on a CUDA GPU through the driver API (ctypes on ``libcuda``).

:func:`cuda_status` says why no GPU can be used (no ``libcuda``, ``cuInit`` failing, no
device), or None.  :class:`CudaModule` loads the PTX of ``rdsl compile --target ptx`` (or of
:func:`jit_ptx`) with ``cuModuleLoadData`` and gives each kernel the CPU kernels' call
interface (:class:`rdsl.runtime.kernel.Kernel`: numpy arrays in and out, the same argument
conversion): a call copies every array the kernel reads or writes to the device, launches
the kernel's grid-stride entry (``compiler/backends/ptx_entry.py``) once, and copies the
outputs and buffers back.  That is simple and correct, not fast: buffers are not kept on the
device between calls.

This module is small on purpose: it has not been run on a GPU here (the machine it was
written on has none), so beyond ``cuda_status`` on a machine without one, nothing of it is
tested.
"""

from __future__ import annotations

import ctypes
from functools import cache
from typing import Any

import numpy as np

from .api import Module
from .kernel import _C_DTYPES, _CTYPES, Kernel

_ITEM = {d: t.itemsize for d, t in _C_DTYPES.items()}  # bytes of an element in memory
_CC_MAJOR, _CC_MINOR = 75, 76  # CU_DEVICE_ATTRIBUTE_COMPUTE_CAPABILITY_*
BLOCK = 128  # threads per block


class CudaUnavailable(RuntimeError):
    """No CUDA GPU can be used (the message says why)."""


@cache
def _driver() -> ctypes.CDLL | str:
    """libcuda after ``cuInit``, or the reason it cannot be used."""
    for name in ("libcuda.so.1", "libcuda.so", "nvcuda.dll"):
        try:
            lib = ctypes.CDLL(name)
            break
        except OSError:
            continue
    else:
        return "the CUDA driver (libcuda) is not installed"
    if lib.cuInit(0) != 0:
        return "the CUDA driver found no usable device (cuInit failed)"
    count = ctypes.c_int(0)
    if lib.cuDeviceGetCount(ctypes.byref(count)) != 0 or count.value == 0:
        return "the CUDA driver reports no GPU"
    return lib


def cuda_status() -> str | None:
    """None when a CUDA GPU can run kernels, else one line saying why not."""
    d = _driver()
    return d if isinstance(d, str) else None


def _cuda() -> ctypes.CDLL:
    d = _driver()
    if isinstance(d, str):
        raise CudaUnavailable(f"no CUDA GPU: {d}")
    return d


def _check(rc: int, what: str) -> None:
    if rc != 0:
        msg = ctypes.c_char_p()
        _cuda().cuGetErrorString(rc, ctypes.byref(msg))
        raise RuntimeError(f"CUDA {what} failed: {(msg.value or b'?').decode()} ({rc})")


def device_arch() -> str:
    """The newest of the ptx target's architectures that device 0 runs (``sm_XY``)."""
    from ..compiler.targets import PTX_ARCHS

    cu = _cuda()
    dev, major, minor = ctypes.c_int(), ctypes.c_int(), ctypes.c_int()
    _check(cu.cuDeviceGet(ctypes.byref(dev), 0), "cuDeviceGet")
    _check(cu.cuDeviceGetAttribute(ctypes.byref(major), _CC_MAJOR, dev), "attribute")
    _check(cu.cuDeviceGetAttribute(ctypes.byref(minor), _CC_MINOR, dev), "attribute")
    cc = 10 * major.value + minor.value
    usable = [a for a in PTX_ARCHS if int(a[3:]) <= cc]
    if not usable:
        raise CudaUnavailable(f"the GPU (sm_{cc}) is older than {PTX_ARCHS[0]}")
    return usable[-1]


class _Entry:
    """A kernel's entry point on the device, called as the C entry ``rdsl_<name>(n, ...)``
    is: with host pointers and strides, which it copies to and from device memory."""

    def __init__(self, function: ctypes.c_void_p, info: dict[str, Any],
                 sizes: dict[int, int]) -> None:
        self.function, self.info, self.sizes = function, info, sizes
        self.argtypes: Any = None
        self.restype: Any = None

    def __call__(self, n: int, *flat: Any) -> None:
        cu = _cuda()
        it = iter(flat)
        values: list[Any] = [ctypes.c_int64(n)]
        copies: list[tuple[int, int, int, bool]] = []  # device, host, bytes, copy back
        try:
            for a in self.info["args"]:
                if a["kind"] == "uniform":
                    v = next(it)  # a number, or already a ctypes value
                    values.append(_CTYPES[a["dtype"]](getattr(v, "value", v)))
                    continue
                ptr = next(it)
                stride = next(it) if a["strided"] else 0
                if a["kind"] == "buffer":
                    nbytes = self.sizes[ptr]
                else:
                    nbytes = (n - 1) * stride + _ITEM[a["dtype"]] if stride else \
                        _ITEM[a["dtype"]]
                values.append(ctypes.c_uint64(self._upload(ptr, nbytes, copies,
                                                           a["kind"] != "varying")))
                if a["strided"]:
                    values.append(ctypes.c_int64(stride))
            mask, mask_stride = next(it), next(it)
            values.append(ctypes.c_uint64(0 if not mask else self._upload(
                mask, (n - 1) * mask_stride + 1, copies, False)))
            values.append(ctypes.c_int64(mask_stride))
            params = (ctypes.c_void_p * len(values))(
                *[ctypes.cast(ctypes.byref(v), ctypes.c_void_p) for v in values])
            grid = max(1, min(-(-n // BLOCK), 65535))
            _check(cu.cuLaunchKernel(self.function, grid, 1, 1, BLOCK, 1, 1, 0, None,
                                     params, None), "cuLaunchKernel")
            _check(cu.cuCtxSynchronize(), "kernel")
            for dev, host, nbytes, back in copies:
                if back:
                    _check(cu.cuMemcpyDtoH_v2(ctypes.c_void_p(host), ctypes.c_uint64(dev),
                                              ctypes.c_size_t(nbytes)), "copy to host")
        finally:
            for dev, *_ in copies:
                cu.cuMemFree_v2(ctypes.c_uint64(dev))

    @staticmethod
    def _upload(host: int, nbytes: int, copies: list, back: bool) -> int:
        if nbytes < 0:
            raise ValueError("negative strides are not supported on the GPU")
        cu = _cuda()
        dev = ctypes.c_uint64()
        _check(cu.cuMemAlloc_v2(ctypes.byref(dev), ctypes.c_size_t(max(nbytes, 1))),
               "cuMemAlloc")
        copies.append((dev.value, host, nbytes, back))
        _check(cu.cuMemcpyHtoD_v2(dev, ctypes.c_void_p(host), ctypes.c_size_t(nbytes)),
               "copy to device")
        return dev.value


class _Library:
    """The loaded CUDA module as :class:`Kernel` sees a library: entry points by symbol."""

    def __init__(self, ptx: str) -> None:
        cu = _cuda()
        dev, ctx = ctypes.c_int(), ctypes.c_void_p()
        _check(cu.cuDeviceGet(ctypes.byref(dev), 0), "cuDeviceGet")
        _check(cu.cuDevicePrimaryCtxRetain(ctypes.byref(ctx), dev), "context")
        _check(cu.cuCtxSetCurrent(ctx), "context")
        self.handle = ctypes.c_void_p()
        _check(cu.cuModuleLoadData(ctypes.byref(self.handle), ptx.encode() + b"\0"),
               "loading the PTX")
        self.sizes: dict[int, int] = {}  # host address -> bytes, of the buffers of a call
        self.info: dict[str, dict[str, Any]] = {}

    def __getattr__(self, symbol: str) -> _Entry:
        if symbol.startswith("__") or symbol not in self.__dict__.get("info", {}):
            raise AttributeError(symbol)
        fn = ctypes.c_void_p()
        _check(_cuda().cuModuleGetFunction(ctypes.byref(fn), self.handle, symbol.encode()),
               f"finding {symbol}")
        return _Entry(fn, self.info[symbol], self.sizes)


class CudaKernel(Kernel):
    """A kernel of a :class:`CudaModule`: the CPU kernel's interface, run on the GPU."""

    def _buffer(self, p: dict[str, Any], value: Any) -> np.ndarray:
        arr = super()._buffer(p, value)
        self._lib.sizes[arr.ctypes.data] = arr.nbytes  # what to copy for the call
        return arr

    def _run(self, n: int, flat: list[Any], threads: int | None) -> list:
        if n > 0:
            self._fn(n, *flat)
        return []


class CudaModule(Module):
    """The kernels of a PTX build on the GPU: ``mod["name"](arrays...)`` as for a CPU one."""

    def __init__(self, manifest: dict[str, Any], ptx: str, **kw: Any) -> None:
        lib = _Library(ptx)
        manifest = dict(manifest, kernels=[dict(k, range_symbol=k["symbol"])
                                           for k in manifest["kernels"]])
        lib.info = {k["symbol"]: k for k in manifest["kernels"]}
        super().__init__(manifest, lib, **kw)  # type: ignore[arg-type]
        self.kernels = {k["name"]: CudaKernel(self, k, lib) for k in manifest["kernels"]}

    @property
    def traces_rays(self) -> bool:
        return False  # the ptx target refuses Embree's ray queries at compile time


def jit_ptx(source_or_path: Any, build: Any, **options: Any) -> CudaModule:
    """Compile for the ptx target of ``build`` and load the kernels on the GPU (no cache)."""
    import time

    from ..compiler import driver
    from ..compiler.backends.clib import manifest
    from ..compiler.backends.ptx import emit_ptx

    _cuda()  # no GPU: say so before compiling
    t0 = time.perf_counter()
    module, _ = driver.compile_kernels(source_or_path, build, **options)
    ptx = emit_ptx(module, build.target)
    return CudaModule(manifest(module, build.target), ptx,
                      compile_seconds=time.perf_counter() - t0)
