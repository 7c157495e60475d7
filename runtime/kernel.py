"""A compiled kernel callable from Python: numpy arrays in, numpy arrays out.

The manifest (written by :mod:`rdsl.compiler.backends.clib`) describes each kernel's
source-level params (scalar, vec, mat, struct, tuple, buffer), their flat leaves, and the
flat C arguments of its entry points.  :class:`Kernel` converts between the two: each leaf
of an array is a strided view of the caller's array (its pointer and byte stride go to C, ABI
2), so no layout is copied, only dtypes the kernel does not take.
"""

from __future__ import annotations

import ctypes
import math
import numbers
import os
import weakref
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from .out_pool import OutputPool
from .overlap import Span, overwritten_inputs, shared_outputs
from .results import build_result, walk_out

DTYPES = {"f32": np.dtype(np.float32), "i32": np.dtype(np.int32),
          "u32": np.dtype(np.uint32), "u64": np.dtype(np.uint64), "bool": np.dtype(np.bool_)}
_C_DTYPES = {**DTYPES, "bool": np.dtype(np.uint8)}  # how each dtype is laid out in C
_CTYPES = {"f32": ctypes.c_float, "i32": ctypes.c_int32, "u32": ctypes.c_uint32,
           "u64": ctypes.c_uint64, "bool": ctypes.c_uint8}
# numpy dtype kinds accepted for each leaf dtype (anything else is a ValueError)
_KINDS = {"f32": "fiu", "i32": "iu", "u32": "iu", "u64": "iu", "bool": "biu"}
_NAMES = {"f32": "float32", "i32": "int32", "u32": "uint32", "u64": "uint64", "bool": "bool"}
# the values an integer leaf holds: other integers are an error, not wrapped around
_RANGES = {"i32": (-(1 << 31), (1 << 31) - 1), "u32": (0, (1 << 32) - 1),
           "u64": (0, (1 << 64) - 1)}

MIN_CHUNK = 4096  # elements per thread-pool task, at least
CHUNKS_PER_THREAD = 16
MAX_THREADS_PER_CORE = 4  # `threads=` above it is cut down to it

# fields a Python caller may leave out of a struct argument, with the value they then take
# in every lane: a Surface made away from a mesh (stdlib/types.rdsl) is on no triangle
OPTIONAL_FIELDS: dict[str, dict[str, Any]] = {"Surface": {"prim": -1, "bary": (0.0, 0.0)}}


def _shape_desc(tj: dict[str, Any]) -> str:
    kind = tj["kind"]
    if kind == "vec":
        return f"(N, {tj['n']})"
    if kind == "mat":
        return f"(N, {tj['n']}, {tj['n']})"
    return "(N,)"


_POOLS: dict[int, ThreadPoolExecutor] = {}


def _thread_count(threads: int | None) -> int:
    """A call's threads: one per core by default, ``MAX_THREADS_PER_CORE`` at most."""
    cores = os.cpu_count() or 1
    return min(cores if threads is None else threads, MAX_THREADS_PER_CORE * cores)


def _pool(threads: int) -> ThreadPoolExecutor:
    """A long-lived pool per thread count: starting threads for every call costs more than
    a small kernel call itself."""
    pool = _POOLS.get(threads)
    if pool is None:
        pool = _POOLS[threads] = ThreadPoolExecutor(max_workers=threads,
                                                    thread_name_prefix="rdsl")
    return pool


class Pending:
    """A kernel call running on the thread pool; ``result()`` waits for it and returns what
    the call returns."""

    def __init__(self, futures: list[Future], keep: Any, finish: Any) -> None:
        self._futures = futures
        self._keep = keep  # the arguments' buffers, alive until the call has run
        self._finish = finish

    def result(self) -> Any:
        for f in self._futures:
            f.result()
        self._futures, self._keep = [], None
        return self._finish()


class Kernel:
    """One compiled kernel.  Call it with arrays (see ``__call__``); ``signature`` shows how."""

    def __init__(self, module: Any, info: dict[str, Any], lib: ctypes.CDLL) -> None:
        # the module holds its kernels; a kernel holds what its calls need (the library, the
        # bound scene) but not the module, so that a module no one holds is freed at once,
        # with its kernels' output pools, rather than by the cycle collector's next round
        self._module = weakref.ref(module)
        self._lib = lib
        self._scene: Any = None  # Module.bind_scene's: kept alive while the kernel is
        self.info = info
        self.name: str = info["name"]
        self.width: int = module.width
        self.params: list[dict[str, Any]] = info["params"]
        self.result: dict[str, Any] = info["result"]
        self.args: list[dict[str, Any]] = info["args"]
        self._arg_index = {a["name"]: i for i, a in enumerate(self.args)}
        self._positional = [p for p in self.params
                            if not p["uniform"] or p["type"]["kind"] == "buffer"]
        self._uniform = {p["name"]: p for p in self.params
                         if p["uniform"] and p["type"]["kind"] != "buffer"}
        self.pool = OutputPool()  # fresh outputs' blocks, reused once no result holds them
        self._strided = [bool(a.get("strided")) for a in self.args]
        self._bind_native(lib)

    @property
    def module(self) -> Any:
        """The module this kernel came from (None once nothing else holds it)."""
        return self._module()

    def _bind_native(self, lib: ctypes.CDLL) -> None:
        """Look the entry points up in ``lib`` and declare their C argument types."""
        info = self.info
        argtypes: list[Any] = []
        for a, strided in zip(self.args, self._strided):
            argtypes.append(ctypes.c_void_p if a["kind"] != "uniform" else _CTYPES[a["dtype"]])
            if strided:
                argtypes.append(ctypes.c_int64)  # the byte stride of the array before it
        argtypes += [ctypes.c_void_p, ctypes.c_int64]  # the mask and its stride
        self._fn = getattr(lib, info["symbol"])
        self._fn.argtypes = [ctypes.c_int64] + argtypes
        self._fn.restype = None
        self._range = getattr(lib, info["range_symbol"])
        self._range.argtypes = [ctypes.c_int64, ctypes.c_int64] + argtypes
        self._range.restype = None

    def __repr__(self) -> str:
        return f"<rdsl.Kernel {self.signature}>"

    @property
    def signature(self) -> str:
        pos = [p["name"] for p in self._positional]
        kw = [f"{n}={p.get('default')!r}" for n, p in self._uniform.items()]
        return f"{self.name}({', '.join(pos + kw + ['mask=None', 'threads=None'])})"

    # -- argument conversion -------------------------------------------------------------
    def _err(self, msg: str) -> ValueError:
        return ValueError(f"{self.name}(): {msg}")

    def _leaf_array(self, path: str, value: Any, dtype: str, tj: dict[str, Any]) -> Any:
        """Check one leaf's array-like (or Python scalar); return an ndarray or a scalar."""
        want = f"expects a {_NAMES[dtype]} array of shape {_shape_desc(tj)}"
        if isinstance(value, (np.ndarray, list, tuple)) or hasattr(value, "__array__"):
            arr = np.asarray(value)
            if arr.dtype.kind not in _KINDS[dtype]:
                raise self._err(f"parameter `{path}` {want}, got dtype {arr.dtype}")
            if arr.ndim == 0:
                return self._scalar(path, arr.item(), dtype, want)
            if arr.ndim != 1:
                raise self._err(f"parameter `{path}` {want}, got shape {arr.shape}")
            self._check_range(path, arr, dtype)
            return arr
        return self._scalar(path, value, dtype, want)

    def _check_range(self, path: str, arr: np.ndarray, dtype: str) -> None:
        """An integer array converted to another integer dtype must hold only values that
        dtype holds (numpy's astype would wrap them around)."""
        if dtype not in _RANGES or arr.dtype == DTYPES[dtype] or arr.dtype.kind not in "iu" \
                or arr.size == 0:
            return
        lo, hi = _RANGES[dtype]
        info = np.iinfo(arr.dtype)
        if lo <= info.min and info.max <= hi:
            return  # every value of the array's dtype fits (int16 for an Int)
        low, high = int(arr.min()), int(arr.max())
        if low < lo or high > hi:
            raise self._err(f"parameter `{path}` expects {_NAMES[dtype]} values ({lo}..{hi}), "
                            f"got {low if low < lo else high} in a {arr.dtype} array")

    def _scalar(self, path: str, value: Any, dtype: str, want: str) -> Any:
        if isinstance(value, (bool, np.bool_)):
            ok = dtype in ("bool", "f32") or isinstance(value, numbers.Integral)
        elif isinstance(value, numbers.Integral):
            lo, hi = _RANGES.get(dtype, (int(value), int(value)))
            if not lo <= int(value) <= hi:
                raise self._err(f"parameter `{path}` expects {_NAMES[dtype]} values "
                                f"({lo}..{hi}), got {value}")
            ok = True
        elif isinstance(value, numbers.Real):
            ok = dtype == "f32"
        else:
            ok = False
        if not ok:
            raise self._err(f"parameter `{path}` {want}, got {type(value).__name__}")
        return value

    def _flatten_varying(self, path: str, value: Any, tj: dict[str, Any],
                         out: list[Any]) -> None:
        """Append the leaf arrays of a varying param (per its type JSON) to ``out``."""
        kind = tj["kind"]
        if kind == "scalar":
            out.append((path, self._leaf_array(path, value, tj["dtype"], tj)))
        elif kind in ("vec", "mat"):
            k = tj["n"] if kind == "vec" else tj["n"] * tj["n"]
            dtype = tj["dtype"]
            want = f"expects a {_NAMES[dtype]} array of shape {_shape_desc(tj)}"
            if isinstance(value, (list, tuple)) and len(value) == k and \
                    all(isinstance(v, numbers.Real) for v in value):
                for v in value:  # one value for every lane
                    out.append((path, self._scalar(path, v, dtype, want)))
                return
            arr = np.asarray(value)
            if arr.dtype.kind not in _KINDS[dtype]:
                raise self._err(f"parameter `{path}` {want}, got dtype {arr.dtype}")
            self._check_range(path, arr, dtype)
            if kind == "mat" and arr.ndim == 3 and arr.shape[1:] == (tj["n"], tj["n"]):
                out.extend((path, arr[:, r, c]) for r in range(tj["n"]) for c in range(tj["n"]))
                return
            if arr.ndim != 2 or arr.shape[1] != k:
                raise self._err(f"parameter `{path}` {want}, got shape {arr.shape}")
            out.extend((path, arr[:, j]) for j in range(k))  # strided views, no copies
        elif kind == "struct":
            if not isinstance(value, dict):
                raise self._err(f"parameter `{path}` expects a dict of fields "
                                f"({', '.join(f for f, _ in tj['fields'])}), "
                                f"got {type(value).__name__}")
            names = [f for f, _ in tj["fields"]]
            extra = set(value) - set(names)
            if extra:
                raise self._err(f"parameter `{path}` has no field `{sorted(extra)[0]}` "
                                f"(fields: {', '.join(names)})")
            optional = OPTIONAL_FIELDS.get(tj.get("name"), {})
            for fname, ft in tj["fields"]:
                if fname not in value and fname not in optional:
                    raise self._err(f"parameter `{path}` is missing field `{fname}`")
                self._flatten_varying(f"{path}.{fname}", value.get(fname, optional.get(fname)),
                                      ft, out)
        elif kind == "tuple":
            elems = tj["elems"]
            if not isinstance(value, (list, tuple)) or len(value) != len(elems):
                raise self._err(f"parameter `{path}` expects a tuple of {len(elems)} values")
            for i, (v, et) in enumerate(zip(value, elems)):
                self._flatten_varying(f"{path}.{i}", v, et, out)
        else:
            raise self._err(f"parameter `{path}` has unsupported type {tj}")

    def _flatten_uniform(self, path: str, value: Any, tj: dict[str, Any],
                         out: list[Any]) -> None:
        kind = tj["kind"]
        if kind == "scalar":
            dtype = tj["dtype"]
            if isinstance(value, np.ndarray) and value.size == 1:
                value = value.reshape(()).item()
            elif isinstance(value, (list, tuple)) and len(value) == 1:
                value = value[0]  # a one-component spectrum
            out.append(self._scalar(path, value, dtype, f"expects a {_NAMES[dtype]} value"))
        elif kind in ("vec", "mat"):
            k = tj["n"] if kind == "vec" else tj["n"] * tj["n"]
            vals = np.asarray(value).reshape(-1).tolist() \
                if isinstance(value, (list, tuple, np.ndarray)) else [value]
            if len(vals) == 1 and k > 1:
                vals = vals * k  # `0.5` where a vector/spectrum is expected
            if len(vals) != k:
                raise self._err(f"parameter `{path}` expects {k} values, got {len(vals)}")
            for v in vals:
                out.append(self._scalar(path, v, tj["dtype"],
                                        f"expects {_NAMES[tj['dtype']]} values"))
        elif kind == "struct":
            if not isinstance(value, dict):
                raise self._err(f"parameter `{path}` expects a dict of fields")
            for fname, ft in tj["fields"]:
                if fname not in value:
                    raise self._err(f"parameter `{path}` is missing field `{fname}`")
                self._flatten_uniform(f"{path}.{fname}", value[fname], ft, out)
        elif kind == "tuple":
            if not isinstance(value, (list, tuple)) or len(value) != len(tj["elems"]):
                raise self._err(f"parameter `{path}` expects a tuple of "
                                f"{len(tj['elems'])} values")
            for i, (v, et) in enumerate(zip(value, tj["elems"])):
                self._flatten_uniform(f"{path}.{i}", v, et, out)
        else:
            raise self._err(f"parameter `{path}` has unsupported type {tj}")

    def _buffer(self, p: dict[str, Any], value: Any) -> np.ndarray:
        dtype = p["type"]["dtype"]
        want = _C_DTYPES[dtype]
        if not isinstance(value, np.ndarray):
            raise self._err(f"buffer parameter `{p['name']}` expects a numpy array of "
                            f"{want.name}, got {type(value).__name__}")
        if value.dtype != want or not value.flags.c_contiguous or not value.flags.writeable:
            raise self._err(f"buffer parameter `{p['name']}` expects a writeable C-contiguous "
                            f"{want.name} array (it is updated in place), got "
                            f"{value.dtype}{'' if value.flags.c_contiguous else ' (strided)'}")
        return value

    # -- calling -------------------------------------------------------------------------
    def __call__(self, *args: Any, mask: Any = None, threads: int | None = None,
                 out: Any = None, wait: bool = True, ranges: Any = None,
                 **kwargs: Any) -> Any:
        """Run the kernel over arrays.

        Positional arguments are the source-level varying params and the buffers, in order
        (they may also be given by keyword); uniform params are keywords (defaults from the
        manifest).  Returns a (N,) array, a (N, k) array for vectors, a dict for structs, a
        tuple for tuples, or None.

        Arrays are read in place, in any layout one stride per axis describes: a C-order
        ``(N, 3)`` array, a Fortran-order one, slices with steps, fields of a record array at
        any offset.  Only an array whose dtype is not the kernel's (float64 for a float
        param, ints for a bool, another byte order) is converted, into a temporary copy.  A
        Python scalar for a varying param is one value for every element (stride 0).

        ``out``: arrays shaped like the result (the result of an earlier call over as many
        elements, or arrays of the caller's own, in any layout: a C-order ``(N, 4)`` array,
        columns of a record array); the kernel writes into them (lanes outside ``mask`` keep
        their old values) and returns ``out``.  ``out`` may be an input itself (``out=x``);
        an input (or mask) in memory that ``out`` overwrites for another element is copied
        first, as numpy's ufuncs do.  Without ``out``, large results are written
        into blocks of ``self.pool`` (see :mod:`rdsl.runtime.out_pool`), which reuses a
        block once no array of an earlier result refers to it: ``r = k(x)`` in a loop
        faults in no fresh pages after the second call.  The fastest loop passes the same
        ``out`` every time (no allocation at all, nothing retained by the pool).

        ``threads``: how many threads run a large call (default: one per core; at most
        ``MAX_THREADS_PER_CORE`` per core).

        ``wait=False`` returns a :class:`Pending` at once, while the thread pool runs the
        call: calls queued together share the pool, so one's last tasks overlap the next's
        first (the arrays passed in must not change until ``result()``).

        ``ranges``: ``[(lo, hi), ...]`` runs exactly those element ranges, each as one task
        on one thread (in order here with ``threads=1``), not chunks the call chooses: for
        ranges that own state (``backward`` gives each gradient rows no other task writes).
        The arguments are converted once for all of them.  CPU targets only."""
        if threads is not None and (isinstance(threads, bool) or
                                    not isinstance(threads, numbers.Integral) or threads < 1):
            raise self._err(f"`threads` expects a number of threads, 1 or more (or None: "
                            f"every core), got {threads!r}")
        values = self._bind(args, kwargs)
        c_vals: list[Any] = [None] * len(self.args)
        strides: list[int] = [0] * len(self.args)
        leaves, leaf_slots = self._convert_params(values, c_vals)
        n = self._length(leaves, mask)
        mask_arr = _mask_array(mask) if mask is not None else None
        if n is None:
            n = 1
        keep = []
        for (_path, v), slot in zip(leaves, leaf_slots):
            a = _leaf_memory(v, self.args[slot]["dtype"])
            keep.append(a)
            c_vals[slot], strides[slot] = a.ctypes.data, a.strides[0]
        out_arrays = self._outputs(out, n, mask is not None, c_vals, strides)
        if out is not None:
            mask_arr = self._copy_overwritten(keep, leaf_slots, mask_arr, c_vals, strides, n)
        for i, a in enumerate(self.args):
            if a["kind"] == "buffer":  # held by the pending call until it is done
                keep.append(c_vals[i])
                c_vals[i] = c_vals[i].ctypes.data
        flat: list[Any] = []
        for v, stride, strided in zip(c_vals, strides, self._strided):
            flat.append(v)
            if strided:
                flat.append(stride)
        if mask_arr is None:
            flat += [None, 0]
        else:
            flat += [mask_arr.ctypes.data, mask_arr.strides[0]]
        futures = self._run(n, flat, threads) if ranges is None else \
            self._run_ranges(n, ranges, flat, threads)
        pending = Pending(futures, (keep, mask_arr, c_vals),
                          lambda: out if out is not None else self._results(out_arrays, n))
        return pending if not wait else pending.result()

    def _bind(self, args: tuple[Any, ...], kwargs: dict[str, Any]) -> dict[str, Any]:
        """The call's arguments by parameter name (positional, then keywords)."""
        pos = self._positional
        if len(args) > len(pos):
            raise self._err(f"expected {len(pos)} positional arguments "
                            f"({', '.join(p['name'] for p in pos)}), got {len(args)}")
        values: dict[str, Any] = {p["name"]: a for p, a in zip(pos, args)}
        for k, v in kwargs.items():
            if k in values:
                raise self._err(f"got multiple values for parameter `{k}`")
            if k not in self._uniform and k not in {p["name"] for p in pos}:
                raise self._err(f"unexpected keyword argument `{k}` (uniform parameters: "
                                f"{', '.join(self._uniform) or 'none'})")
            values[k] = v
        missing = [p["name"] for p in pos if p["name"] not in values]
        if missing:
            raise self._err(f"missing argument for parameter `{missing[0]}` (expected "
                            f"{', '.join(p['name'] for p in pos)})")
        return values

    def _convert_params(self, values: dict[str, Any], c_vals: list[Any]
                        ) -> tuple[list[tuple[str, Any]], list[int]]:
        """Fill ``c_vals`` with the buffers and uniform scalars; return the varying leaves
        (path, array or scalar) and their argument slots, converted later once N is known."""
        leaves: list[tuple[str, Any]] = []
        leaf_slots: list[int] = []
        for p in self.params:
            name, tj = p["name"], p["type"]
            if tj["kind"] == "buffer":
                slot = self._arg_index[p["leaves"][0] if p.get("leaves") else name]
                c_vals[slot] = self._buffer(p, values[name])
                continue
            if p["uniform"]:
                value = values.get(name, p.get("default"))
                if value is None and p.get("default") is not None:
                    raise self._err(f"uniform parameter `{name}` got None (leave it out for "
                                    f"its default, {p['default']!r})")
                if value is None:
                    raise self._err(f"missing value for uniform parameter `{name}` "
                                    "(it has no default)")
                flat: list[Any] = []
                self._flatten_uniform(name, value, tj, flat)
                for leaf, v in zip(p["leaves"], flat):
                    dt = self.args[self._arg_index[leaf]]["dtype"]
                    c_vals[self._arg_index[leaf]] = _CTYPES[dt](_c_scalar(v, dt))
                continue
            flat_v: list[tuple[str, Any]] = []
            self._flatten_varying(name, values[name], tj, flat_v)
            for leaf, item in zip(p["leaves"], flat_v):
                leaves.append(item)
                leaf_slots.append(self._arg_index[leaf])
        return leaves, leaf_slots

    def _length(self, leaves: list[tuple[str, Any]], mask: Any) -> int | None:
        """N, from the first array (the mask included); every array must agree."""
        n, n_from = None, None
        for path, v in leaves:
            if isinstance(v, np.ndarray):
                if n is None:
                    n, n_from = len(v), path
                elif len(v) != n:
                    raise self._err(f"parameter `{path}` has {len(v)} elements, expected {n} "
                                    f"(the length of `{n_from}`)")
        if mask is not None:
            m = np.asarray(mask)
            if m.ndim != 1 or m.dtype.kind not in "biu":
                raise self._err(f"`mask` expects a bool array of shape (N,), got "
                                f"{m.dtype} array of shape {m.shape}")
            if n is None:
                n = len(m)
            elif len(m) != n:
                raise self._err(f"`mask` has {len(m)} elements, expected {n}")
        return n

    def _outputs(self, out: Any, n: int, masked: bool, c_vals: list[Any],
                 strides: list[int]) -> dict[str, Any]:
        """Point the output arguments at ``out``'s arrays, or at fresh ones (returned by
        name)."""
        outs = [(i, a) for i, a in enumerate(self.args) if a["kind"] == "output"]
        out_arrays: dict[str, Any] = {}
        if out is not None:
            arrays = self._out_leaves(out, n)
            for (i, _), arr in zip(outs, arrays):
                c_vals[i], strides[i] = arr.ctypes.data, arr.strides[0]
            spans = [Span(c_vals[i], strides[i], arr.itemsize)
                     for (i, _), arr in zip(outs, arrays)]
            shared = shared_outputs(spans, arrays, n)
            if shared is not None:
                a, b = (outs[j][1]["name"] for j in shared)
                raise self._err(f"`out` gives results `{a}` and `{b}` the same memory (one "
                                "would overwrite the other)")
            return out_arrays
        # outputs of one dtype are the rows of one block, in result order: a vector
        # result is then a view (no copy), and consecutive leaves are one contiguous array;
        # a masked call's lanes outside the mask are 0
        blocks = {}
        for dt in dict.fromkeys(a["dtype"] for _, a in outs):
            count = sum(1 for _, a in outs if a["dtype"] == dt)
            blocks[dt] = [self.pool.block((count, n), _C_DTYPES[dt], zero=masked), 0]
        for i, a in outs:
            blk = blocks[a["dtype"]]
            arr = blk[0][blk[1]]
            blk[1] += 1
            out_arrays[a["name"]] = arr
            c_vals[i], strides[i] = arr.ctypes.data, arr.strides[0]
        return out_arrays

    def _copy_overwritten(self, inputs: list[np.ndarray], slots: list[int],
                          mask_arr: np.ndarray | None, c_vals: list[Any], strides: list[int],
                          n: int) -> np.ndarray | None:
        """Copy the inputs (the mask too) that the ``out=`` arrays in ``c_vals`` would
        overwrite before another lane reads them (see :mod:`rdsl.runtime.overlap`); return
        the mask to pass."""
        outs = [Span(c_vals[i], strides[i], _C_DTYPES[a["dtype"]].itemsize)
                for i, a in enumerate(self.args) if a["kind"] == "output"]
        spans = [Span(c_vals[s], strides[s], a.itemsize) for a, s in zip(inputs, slots)]
        if mask_arr is not None:
            spans.append(Span(mask_arr.ctypes.data, mask_arr.strides[0], 1))
        for j in overwritten_inputs(spans, outs, n):
            if j == len(inputs):
                mask_arr = mask_arr.copy()
                continue
            a = inputs[j] = inputs[j].copy()
            c_vals[slots[j]], strides[slots[j]] = a.ctypes.data, a.strides[0]
        return mask_arr

    def _run(self, n: int, flat: list[Any], threads: int | None) -> list[Future]:
        """Run over [0, n) with the entry point's arguments ``flat`` (after ``n``): on this
        thread, or as tasks of the thread pool (their futures are returned, not waited
        for)."""
        if n <= 0:
            return []
        threads = _thread_count(threads)
        if threads == 1 or n < 2 * MIN_CHUNK:
            self._fn(n, *flat)
            return []
        W = max(self.width, 1)
        # tasks of at least MIN_CHUNK elements, as many for every thread: with one task
        # more for some, the others would wait for it at the end of every call
        tasks = max(1, min(threads * CHUNKS_PER_THREAD, n // MIN_CHUNK))
        tasks = -(-tasks // threads) * threads
        chunk = -(-math.ceil(n / tasks) // W) * W
        bounds = [(b, min(b + chunk, n)) for b in range(0, n, chunk)]
        pool = _pool(threads)
        return [pool.submit(self._range, b, e, *flat) for b, e in bounds]

    def _run_ranges(self, n: int, ranges: Any, flat: list[Any],
                    threads: int | None) -> list[Future]:
        """Each of ``ranges`` as one task (here with ``threads=1``); the pool's futures."""
        bounds = [(int(lo), int(hi)) for lo, hi in ranges]
        bad = next((b for b in bounds if not 0 <= b[0] <= b[1] <= n), None)
        if bad is not None:
            raise self._err(f"`ranges` has {bad}, outside the call's {n} elements")
        if _thread_count(threads) == 1:
            for lo, hi in bounds:
                self._range(lo, hi, *flat)
            return []
        pool = _pool(_thread_count(threads))
        return [pool.submit(self._range, lo, hi, *flat) for lo, hi in bounds if hi > lo]

    def _out_leaves(self, result: Any, n: int) -> list[np.ndarray]:
        """The arrays of ``result`` (shaped as ``_results`` builds it, any strides) for the
        output arguments, in their order, checked to be writeable views of ``n`` elements of
        the right dtype (bools as uint8, as the kernel writes them)."""
        bad = self._err(f"`out` is not a result of this kernel over {n} elements (nor "
                        "writeable arrays of its dtypes shaped like one)")
        leaves: list[np.ndarray] = []
        tj = self.result.get("type")
        if tj is not None and not walk_out(result, tj, n, leaves):
            raise bad
        names = self.result["leaves"]
        if len(leaves) != len(names):
            raise bad
        by_name = dict(zip(names, leaves))
        arrays = []
        for a in self.args:
            if a["kind"] != "output":
                continue
            leaf = by_name[a["name"]]
            if leaf.dtype != DTYPES[a["dtype"]] or not leaf.flags.writeable:
                raise bad
            arrays.append(leaf.view(np.uint8) if a["dtype"] == "bool" else leaf)
        return arrays

    def _results(self, out_arrays: dict[str, np.ndarray], n: int) -> Any:
        tj = self.result.get("type")
        if tj is None:
            return None
        arrays = iter([out_arrays[name] for name in self.result["leaves"]])
        return build_result(tj, arrays, n)


def _leaf_memory(v: Any, dtype: str) -> np.ndarray:
    """The 1-D array the kernel reads a varying leaf from (its stride is the call's): the
    array itself when its dtype is the kernel's, whatever its strides (no copy); a converted
    copy when the dtype differs (float64 for f32, ints for bool, another byte order); one
    element read with stride 0 for a scalar.  Bools are passed as their bytes (uint8)."""
    want = DTYPES[dtype]
    if not isinstance(v, np.ndarray):
        a = np.full(1, v, dtype=want)
        a = np.lib.stride_tricks.as_strided(a, shape=(1,), strides=(0,))
    elif v.dtype == want:
        a = v
    elif dtype == "bool" and v.dtype.kind != "b":
        a = v != 0
    else:
        a = v.astype(want)
    return a.view(np.uint8) if dtype == "bool" else a


def _mask_array(mask: Any) -> np.ndarray:
    """The mask as the kernel reads it: a uint8 view of a bool array (any strides), else a
    converted copy (nonzero = active)."""
    m = np.asarray(mask)
    return (m if m.dtype.kind == "b" else m != 0).view(np.uint8)


def _c_scalar(v: Any, dtype: str) -> Any:
    if dtype == "f32":
        return float(v)
    if dtype == "bool":
        return 1 if v else 0
    bits = 64 if dtype == "u64" else 32
    iv = int(v) & ((1 << bits) - 1)
    if dtype == "i32" and iv >= 1 << 31:
        iv -= 1 << 32
    return iv
