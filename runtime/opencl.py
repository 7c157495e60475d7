"""Kernels of target ``opencl`` run through ``pyopencl`` (PoCL on a CPU, any OpenCL device
elsewhere), with the call interface of the CPU kernels: numpy arrays in, numpy arrays out.

:func:`load_opencl` builds the ``.cl`` program that ``rdsl compile --target opencl`` wrote
(``rdsl.compiler.backends.opencl``) and returns a :class:`ClModule` of :class:`ClKernel` s.
A kernel keeps one device buffer per argument, made on the first call and reused by every
later call over as many elements or fewer (grown when a call needs more).  A call copies
its inputs to the device, runs one work-item per W elements (the build's width) and copies
the results back.

pyopencl and the OpenCL platform are looked up lazily: without them, loading an ``opencl``
build raises one clear :class:`OpenCLUnavailable` naming the package to install.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..compiler.diagnostics import CompileError
from .api import Module
from .kernel import _C_DTYPES, Kernel, Pending, _leaf_memory, _mask_array

# the numpy type of a uniform argument of each dtype (OpenCL kernels take no bools: int)
_UNIFORM_NP = {"f32": np.float32, "i32": np.int32, "u32": np.uint32, "u64": np.uint64,
               "bool": np.int32}
LOCAL_SIZE = 16  # work-items per work-group (each runs W lanes; 4 to 64 measure alike)

_CONTEXT: list[Any] = []  # (context, queue, device name), made once per process


class OpenCLUnavailable(CompileError):
    """No way to run OpenCL here: pyopencl or an OpenCL platform (driver) is missing."""


def opencl_context() -> tuple[Any, Any, str]:
    """The process's OpenCL context, command queue and device name (the first device of
    the first platform that has one); :class:`OpenCLUnavailable` when there is none."""
    if _CONTEXT:
        return _CONTEXT[0]
    try:
        import pyopencl as cl
    except ImportError:
        raise OpenCLUnavailable("target opencl needs the Python package pyopencl "
                                "(pip install pyopencl)") from None
    try:
        platforms = cl.get_platforms()
    except cl.Error:  # ocl-icd reports "no platform" as an error
        platforms = []
    devices = [d for p in platforms for d in _devices(p)]
    if not devices:
        raise OpenCLUnavailable("target opencl found no OpenCL platform: install one, e.g. "
                                "PoCL for the CPU (Debian: apt-get install pocl-opencl-icd)")
    ctx = cl.Context([devices[0]])
    # profiling: each call records its kernel's own time (ClKernel.last_device_seconds)
    queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    _CONTEXT.append((ctx, queue, devices[0].name.strip()))
    return _CONTEXT[0]


def _devices(platform: Any) -> list[Any]:
    import pyopencl as cl

    try:
        return platform.get_devices()
    except cl.Error:
        return []


def build_program(source: str, options: list[str], where: str) -> Any:
    """The built OpenCL program of ``source`` (pyopencl caches the binary on disk)."""
    ctx, _, device = opencl_context()  # first: it says what is missing
    import pyopencl as cl

    try:
        return cl.Program(ctx, source).build(options=options)
    except cl.RuntimeError as e:
        raise CompileError(f"{where}: the OpenCL compiler of `{device}` failed:\n{e}") from None


def load_opencl(cl_path: Path, manifest: dict[str, Any], from_cache: bool = False,
                compile_seconds: float = 0.0) -> ClModule:
    """Build ``cl_path`` (what ``rdsl compile --target opencl`` wrote) for this machine's
    OpenCL device; ``manifest``: its ``.json``."""
    try:
        source = cl_path.read_text()
    except OSError as e:
        raise CompileError(f"cannot read {cl_path}: {e.strerror or e}") from None
    program = build_program(source, list(manifest.get("cl_build_options", [])), str(cl_path))
    return ClModule(manifest, program, cl_path, from_cache, compile_seconds)


class ClModule(Module):
    """A loaded OpenCL program: the kernels of a :class:`rdsl.Module`, run on the device."""

    def __init__(self, manifest: dict[str, Any], program: Any, path: Path | None = None,
                 from_cache: bool = False, compile_seconds: float = 0.0) -> None:
        self.program = program
        super().__init__(manifest, None, path, from_cache, compile_seconds)

    def _make_kernel(self, info: dict[str, Any], lib: Any) -> Kernel:
        return ClKernel(self, info, self.program)

    def resident(self, array: np.ndarray) -> DeviceBuffer:
        """A copy of ``array`` on the device, for the kernels' buffer parameters (read and
        written there, without copies; ``get()`` reads it back)."""
        return DeviceBuffer(array)

    @property
    def device(self) -> str:
        """The name of the OpenCL device the kernels run on."""
        return opencl_context()[2]

    @property
    def traces_rays(self) -> bool:
        return False  # a ray query is a diagnostic on this target until the rdsl BVH lands

    def bind_scene(self, scene: Any) -> None:
        raise ValueError("this library traces no rays, so it takes no scene")


class DeviceBuffer:
    """A numpy array's copy in device memory.  Passed for a kernel's buffer parameter it is
    used in place: no copy to or from the host (the renderer keeps the scene's buffers and
    the film there); :meth:`get` returns its contents as a new array."""

    def __init__(self, array: np.ndarray) -> None:
        import pyopencl as cl

        ctx = opencl_context()[0]
        host = np.ascontiguousarray(array)
        self.shape, self.dtype = host.shape, host.dtype
        flags = cl.mem_flags.READ_WRITE
        if host.nbytes:
            self.buffer = cl.Buffer(ctx, flags | cl.mem_flags.COPY_HOST_PTR, hostbuf=host)
        else:  # OpenCL has no empty buffers
            self.buffer = cl.Buffer(ctx, flags, 16)

    def get(self) -> np.ndarray:
        """The buffer's contents, read back from the device."""
        import pyopencl as cl

        out = np.empty(self.shape, self.dtype)
        if out.nbytes:
            cl.enqueue_copy(opencl_context()[1], out, self.buffer, is_blocking=True)
        return out


class ClKernel(Kernel):
    """One OpenCL kernel, called like a CPU :class:`Kernel` (``threads`` is ignored: the
    OpenCL runtime spreads the work-items over the device)."""

    def __init__(self, module: Any, info: dict[str, Any], program: Any) -> None:
        super().__init__(module, info, None)
        import pyopencl as cl

        self._cl = cl
        self._kernel = getattr(program, info["symbol"])
        self._device: dict[int, Any] = {}  # argument slot (or -1: the mask) -> cl.Buffer
        # one call at a time: calls share the device buffers above and the kernel's
        # arguments (two threads calling at once crashed in pyopencl)
        self._calling = threading.Lock()
        self.last_device_seconds = 0.0  # the last call's kernel alone, without copies

    def _bind_native(self, lib: Any) -> None:
        pass  # no C entry points: the program's kernel is looked up in __init__

    def _buffer(self, p: dict[str, Any], value: Any) -> Any:
        if isinstance(value, DeviceBuffer):
            want = _C_DTYPES[p["type"]["dtype"]]
            if value.dtype != want:
                raise self._err(f"buffer parameter `{p['name']}` expects {want.name}, got a "
                                f"device buffer of {value.dtype}")
            return value
        return super()._buffer(p, value)

    # -- calling -------------------------------------------------------------------------
    def __call__(self, *args: Any, mask: Any = None, threads: int | None = None,
                 out: Any = None, wait: bool = True, **kwargs: Any) -> Any:
        """Run the kernel over arrays: the arguments, ``mask`` and ``out`` of
        :meth:`Kernel.__call__`.  The call has finished when it returns (``wait=False``
        gives a :class:`Pending` that is already done)."""
        values = self._bind(args, kwargs)
        vals: list[Any] = [None] * len(self.args)
        leaves, slots = self._convert_params(values, vals)
        n = self._length(leaves, mask)
        if n is None:  # scalars only: one element
            n = 1
        for (_path, v), slot in zip(leaves, slots):
            vals[slot] = v
        masked = mask is not None
        if out is not None:
            out_list = self._out_leaves(out, n)
            out_arrays: dict[str, np.ndarray] = {}
        else:
            out_list, out_arrays = self._fresh_outputs(n)
        with self._calling:
            self.launch(n, vals, _mask_array(mask) if masked else None, out_list)
        result = out if out is not None else self._results(out_arrays, n)
        pending = Pending([], None, lambda: result)
        return pending if not wait else pending.result()

    def _fresh_outputs(self, n: int) -> tuple[list[np.ndarray], dict[str, np.ndarray]]:
        """Zeroed output arrays, one block per dtype in result order (so that a vector
        result is a view of its block, as the CPU kernels give it)."""
        outs = [a for a in self.args if a["kind"] == "output"]
        blocks = {dt: [np.zeros((sum(a["dtype"] == dt for a in outs), n), _C_DTYPES[dt]), 0]
                  for dt in dict.fromkeys(a["dtype"] for a in outs)}
        arrays: dict[str, np.ndarray] = {}
        order = []
        for a in outs:
            blk = blocks[a["dtype"]]
            arrays[a["name"]] = blk[0][blk[1]]
            order.append(blk[0][blk[1]])
            blk[1] += 1
        return order, arrays

    def _buffer_for(self, slot: int, nbytes: int) -> Any:
        """The device buffer of argument ``slot``, at least ``nbytes`` long (reused)."""
        buf = self._device.get(slot)
        if buf is None or buf.size < nbytes:
            ctx = opencl_context()[0]
            buf = self._device[slot] = self._cl.Buffer(ctx, self._cl.mem_flags.READ_WRITE,
                                                       max(nbytes, 16))
        return buf

    # long: one pass over the arguments (inputs up, the launch, outputs and buffers down)
    def launch(self, n: int, vals: list[Any], mask: np.ndarray | None,
               outs: list[np.ndarray]) -> None:
        """Run over ``n`` elements.  ``vals``: per argument of the manifest, an array or a
        scalar for a varying input (a scalar is every element's value), the value of a
        uniform, the numpy array of a buffer (updated in place) or a
        :class:`DeviceBuffer`; ``outs``: the output
        arrays in order (1-D, any stride; bools as uint8)."""
        if n == 0:  # nothing to run (and a buffer cannot be mapped over no bytes)
            self.last_device_seconds = 0.0
            return
        cl = self._cl
        queue = opencl_context()[1]
        items = -(-n // self.width)  # work-items: W elements each
        pad = items * self.width
        kargs: list[Any] = [np.int64(n)]
        back: list[tuple[np.ndarray, Any]] = []  # host array, device buffer
        out_iter = iter(outs)
        for slot, a in enumerate(self.args):
            v, kind, dt = vals[slot], a["kind"], a["dtype"]
            if kind == "uniform":
                kargs.append(_UNIFORM_NP[dt](v.value if hasattr(v, "value") else v))
                continue
            if isinstance(v, DeviceBuffer):  # already on the device: used in place
                kargs.append(v.buffer)
                continue
            broadcast = kind == "varying" and not isinstance(v, np.ndarray)
            if kind == "varying":  # one element (read with stride 0) for a scalar
                host = _leaf_memory(v, dt)[:1 if broadcast else None]
            else:  # a buffer is updated in place; an output written back
                host = v if kind == "buffer" else next(out_iter)
                back.append((host, None))
            # the arrays a work-item reads W at a time hold n rounded up to W elements
            size = host.nbytes if kind == "buffer" or broadcast else pad * host.itemsize
            buf = self._buffer_for(slot, size)
            if kind != "output" or mask is not None:  # masked lanes keep the output's value
                self._write(queue, buf, host)
            if kind != "varying":
                back[-1] = (host, buf)
            kargs.append(buf)
            if kind == "varying":
                kargs.append(np.int32(0 if broadcast else 1))
        mbuf = self._buffer_for(-1, pad if mask is not None else 1)
        if mask is not None:
            self._write(queue, mbuf, mask)
        kargs += [mbuf, np.int32(mask is not None)]
        self._kernel.set_args(*kargs)
        groups = -(-items // LOCAL_SIZE)
        event = cl.enqueue_nd_range_kernel(queue, self._kernel, (groups * LOCAL_SIZE,),
                                           (LOCAL_SIZE,))
        for host, buf in back:
            mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.READ, 0, host.shape,
                                              host.dtype, is_blocking=True)
            with mapped.base:
                host[...] = mapped
        queue.finish()
        self.last_device_seconds = (event.profile.end - event.profile.start) * 1e-9

    def _write(self, queue: Any, buf: Any, host: np.ndarray) -> None:
        """Copy 1-D ``host`` (any stride) to the start of ``buf``: through a mapping, one
        strided pass (no staging copy; on a CPU device the mapping is the buffer itself)."""
        cl = self._cl
        mapped, _ = cl.enqueue_map_buffer(queue, buf, cl.map_flags.WRITE_INVALIDATE_REGION, 0,
                                          host.shape, host.dtype, is_blocking=True)
        with mapped.base:
            mapped[...] = host


__all__ = ["ClKernel", "ClModule", "DeviceBuffer", "OpenCLUnavailable", "load_opencl",
           "opencl_context"]
