"""Per-scene precomputation: the values of a plugin's ``table`` functions.

A ``table(n = 64, lo = 0.0, hi = 1.0, error = 1e-4) fn t(x: Float) -> Float`` in a plugin
is sampled at the ``n`` points of ``linspace(lo, hi, n)`` once per scene, for each instance
(its parameters fixed), and calls of ``t(x)`` read the samples back with linear
interpolation (:func:`build_read`).  A ``table fn c() -> Float`` is one value per instance.
``specialize`` fills them at compile time; the generic build (parameters read at run time)
lays them out at the end of ``PRM`` and the runtime fills them at scene load, both with
:func:`tabulate`.

A ``table(sum = N) fn t(k: Int)`` is one value: the sum, in float64, of its N terms
``t(0) .. t(N-1)``, which are sampled as a table's points are.

The samples are computed natively: the table function becomes a kernel (the pipeline and
the LLVM backend for the host's vectors at the quick tier's O0, 0.4 s, the points in its lanes;
kept per function in the process and in the kernel cache on disk, so that another scene
or process with the same plugin builds nothing), mapped over the sample points with the
instance's parameters as uniform arguments.  Its code depends on the plugin, never on the values, so every instance
and scene reuses it.  Tables are the place for the
expensive integrals (Mitsuba's are 64 x 32 x 32 and 64 x 128 x 128 evaluations of a
microfacet integrand), far beyond what the reference interpreter runs in a second; small
pure computations are folded by the ``evaluate`` pass instead.

A table may depend on the plugin's ``Float``, ``Int`` and ``Bool`` parameters only (a
texture varies over the surface); anything else it uses is a diagnostic.
"""

from __future__ import annotations

import ctypes
import threading
from typing import Any

import numpy as np

from ..core.cachedir import write_atomically
from ..core.scene_spec import Instance, Slot, TextureRef
from .diagnostics import CompileError
from .ir import (
    F32,
    I32,
    BufferType,
    Builder,
    Function,
    Module,
    Op,
    Param,
    ScalarType,
    Value,
    clone_function,
)

_CTYPES = {"f32": ctypes.c_float, "i32": ctypes.c_int32, "u32": ctypes.c_uint32,
           "u64": ctypes.c_uint64, "bool": ctypes.c_uint8}
_NP = {"f32": np.float32, "i32": np.int32, "u32": np.uint32, "u64": np.uint64, "bool": np.bool_}
_kernels: dict[str, Any] = {}  # printed IR of the table function -> its compiled kernel
TABLE_TARGET = "host"  # what a table's kernel is compiled for (its points are its lanes)
_lock = threading.Lock()


def sample_points(options: dict[str, Any]) -> np.ndarray:
    """Where a table is sampled: ``linspace(lo, hi, n)``; the term indices 0 .. N-1 of a
    ``sum`` table (int32); one point, 0, for a value."""
    if "sum" in options:
        return np.arange(options["sum"], dtype=np.int32)
    if "n" not in options:
        return np.zeros(1, np.float32)
    return np.linspace(options["lo"], options["hi"], options["n"]).astype(np.float32)


def table_size(options: dict[str, Any]) -> int:
    return int(options.get("n", 1))


def table_params(read: Function, inst: Instance) -> dict[str, Any]:
    """An instance's values of the scalar parameters a table's read function takes (colours
    and textures left out: a table cannot depend on them, see :func:`tabulate`)."""
    out = {}
    for p in read.params:
        value = inst.params.get(p.value.name or "", p.default)
        if isinstance(p.value.type, ScalarType) and not isinstance(value, Slot):
            out[p.value.name or ""] = value  # a texture here: an error if the table uses it
    return out


def tabulate(module: Module, options: dict[str, Any], params: dict[str, Any]) -> np.ndarray:
    """The samples (float32) of the table function ``options["fn"]`` of ``module`` with its
    plugin parameters set to ``params`` (by name; missing ones take their defaults)."""
    fn = module.functions[options["fn"]]
    has_x = bool(options.get("n")) or "sum" in options
    names, text = _source(module, fn, has_x)
    xs = sample_points(options)
    path = _disk_entry(text, xs, params)
    out = load_samples(path, len(xs)) if path is not None else None
    if out is None:
        out = _kernel(module, names, text, fn, has_x)(xs, params)
        if path is not None:
            store_samples(path, out)
    if "sum" in options:  # the terms summed in float64 (numpy's pairwise sum)
        return np.array([np.sum(out, dtype=np.float64)], np.float32)
    return out


def _disk_entry(text: str, xs: np.ndarray, params: dict[str, Any]) -> Any:
    """Where the samples of the table function printed as ``text`` at ``xs`` with
    ``params`` are kept across processes (``<cache>/tables/<sha256>.npy``: a test suite or a
    new scene loads the same plugin with the same values again), or None if a value is not
    a plain number or None (a texture, a colour: left to the kernel call, which may diagnose
    it; an entry exists only for inputs that computed without error).  The key: the
    printed IR of the function and all it calls (their parameters' defaults included),
    the points, the values, rdsl's version, the compiler's fingerprint and LLVM's."""
    import platform

    plain = (bool, int, float, np.bool_, np.integer, np.floating)
    if not all(v is None or isinstance(v, plain) for v in params.values()):
        return None
    return _cache_file("", ".npy", platform.machine(), text, xs.tobytes(),
                       repr(sorted(params.items())))


def _cache_file(prefix: str, suffix: str, *parts: str | bytes) -> Any:
    """``<cache>/tables/<prefix><sha256><suffix>``: the hash of rdsl's version, the
    compiler's fingerprint, llvmlite's version and ``parts``."""
    import hashlib

    import llvmlite

    from .. import __version__
    from ..core.cachedir import cache_dir, compiler_fingerprint

    h = hashlib.sha256()
    for part in (__version__, compiler_fingerprint(), llvmlite.__version__, *parts):
        b = part if isinstance(part, bytes) else part.encode()
        h.update(f"{len(b)}:".encode() + b)
    return cache_dir() / "tables" / f"{prefix}{h.hexdigest()}{suffix}"


def load_samples(path: Any, n: int) -> np.ndarray | None:
    """The ``n`` float32 samples kept in ``path`` (``.npy``), or None (none there, or damaged)."""
    try:
        got = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    return got if got.dtype == np.float32 and got.shape == (n,) else None


def store_samples(path: Any, samples: np.ndarray) -> None:
    write_atomically(path, lambda f: np.save(f, samples, allow_pickle=False))


class _Kernel:
    """A compiled table function: ``(xs, params) -> values``."""

    def __init__(self, name: str, lib: Any, symbol: str, address: int, args: list[Any],
                 defaults: dict[str, Any], used: set[str]) -> None:
        self.name, self.used = name, used
        self.lib = lib  # keeps the code mapped
        self.symbol = symbol  # its entry point in lib
        self.args = args  # the CArgs after n
        self.defaults = defaults  # the uniform parameters' defaults, by name
        argtypes: list[Any] = [ctypes.c_int64]
        for a in args:
            argtypes += ([ctypes.c_void_p, ctypes.c_int64] if a.strided
                         else [_CTYPES[a.dtype]])
        argtypes += [ctypes.c_void_p, ctypes.c_int64]
        self.fn = ctypes.CFUNCTYPE(None, *argtypes)(address)

    def __call__(self, xs: np.ndarray, values: dict[str, Any]) -> np.ndarray:
        x_type = next((_NP[a.dtype] for a in self.args if a.kind == "varying"), np.float32)
        xs = np.ascontiguousarray(xs, x_type)
        out = np.zeros(len(xs), np.float32)
        defaults = self.defaults
        call: list[Any] = [len(xs)]
        for a in self.args:
            if a.kind == "varying":
                call += [xs.ctypes.data, 4]
            elif a.kind == "output":
                call += [out.ctypes.data, 4]
            else:
                v = values.get(a.name, defaults.get(a.name))
                if isinstance(v, TextureRef):
                    if a.name in self.used:
                        raise CompileError(f"table `{self.name}` depends on `{a.name}`, which "
                                           "the scene sets by a texture; a table's parameters "
                                           "must be numbers")
                    v = defaults.get(a.name, 0)
                if v is None or isinstance(v, (tuple, list)):
                    raise CompileError(f"table parameter `{a.name}`: expected one number, "
                                       f"got {v!r}")
                call.append(_CTYPES[a.dtype](_NP[a.dtype](v).item()))
        call += [None, 0]
        self.fn(*call)
        return out


def _source(module: Module, fn: Function, has_x: bool) -> tuple[list[str], str]:
    """The functions the table kernel of ``fn`` is built from, and their printed IR: what
    its code depends on (the key of :func:`_kernel` and of the samples on disk)."""
    from .printer import print_function

    names = _reachable(module, fn)
    return names, repr(has_x) + "".join(print_function(module.functions[n]) for n in names)


def _kernel(module: Module, names: list[str], key: str, fn: Function, has_x: bool
            ) -> _Kernel:
    with _lock:
        k = _kernels.get(key) or _load_kernel(key, fn.name)
        if k is None:
            sub = Module(structs=dict(module.structs))
            for name in names:  # a copy: the passes below rewrite what they compile
                f = clone_function(module.functions[name])
                f.attrs.pop("export", None)
                sub.add(f)
            k = _compile(sub, fn, has_x)
            _store_kernel(key, k)
        _kernels[key] = k
        return k


# A compiled table kernel is kept on disk too (``<cache>/tables/kernel-<sha256>.pickle``:
# its library's path and how to call it), so that a new scene with the same plugin and
# other values compiles nothing (a rough plastic's two tables took 0.9 s to build).


def _kernel_entry(key: str) -> Any:
    from .build import Build

    t = Build.of(TABLE_TARGET, "rgb").target
    return _cache_file("kernel-", ".pickle", t.triple, t.cpu, t.features, key)


def _load_kernel(key: str, name: str) -> _Kernel | None:
    """The kernel a process built before for ``key``, or None (none, or its library gone)."""
    import pickle

    from .backends.native_lib import address_of

    try:
        entry = pickle.loads(_kernel_entry(key).read_bytes())
        lib = ctypes.CDLL(entry["so"])
    except Exception:  # noqa: BLE001 - missing, damaged or stale: build it again
        return None
    address = address_of(lib, entry["symbol"])
    if not address:
        return None
    return _Kernel(name, lib, entry["symbol"], address, entry["args"], entry["defaults"],
                   entry["used"])


def _store_kernel(key: str, k: _Kernel) -> None:
    """Record ``k`` for :func:`_load_kernel` (atomically; silently not in a read-only
    cache).  Its library is already in the native cache, under a name of its own."""
    import pickle

    entry = {"so": k.lib._name, "symbol": k.symbol, "args": k.args,
             "defaults": k.defaults, "used": k.used}
    write_atomically(_kernel_entry(key), lambda f: pickle.dump(entry, f))


def _reachable(module: Module, fn: Function) -> list[str]:
    """``fn`` and every function it calls, sorted by name."""
    names, todo = set(), [fn.name]
    while todo:
        name = todo.pop()
        if name in names:
            continue
        names.add(name)
        todo += [i.attrs["callee"] for i in module.functions[name].walk() if i.op is Op.CALL]
    return sorted(names)


def _compile(sub: Module, fn: Function, has_x: bool) -> _Kernel:
    """Wrap ``fn`` as the kernel ``tabulate(x, params...)``, compile it for the host
    and load it (compiler/backends/native_lib.py); the cycle collector paused, as for
    every compile (core/gcpause.py: a table is built at scene load, outside one)."""
    from ..core.gcpause import gc_paused

    with gc_paused():
        return _compile_paused(sub, fn, has_x)


def _compile_paused(sub: Module, fn: Function, has_x: bool) -> _Kernel:
    from .backends.base import c_args, c_name
    from .backends.llvm import optimized_module
    from .backends.native_lib import address_of, load_native
    from .build import Build
    from .driver import pipeline, run_passes
    from .passes.inline import Inline
    from .passes.optimize import Optimize

    wrapper = _wrapper(sub, sub.functions[fn.name], has_x)
    run_passes(sub, [Inline(), Optimize()], verify=False)
    used = {v for i in wrapper.walk() for v in i.operands}
    used_names = {p.value.name or "" for p in wrapper.params if p.value in used}
    for p in wrapper.params:
        if not isinstance(p.value.type, ScalarType) and p.value in used:
            raise CompileError(f"table `{fn.name}` depends on the parameter `{p.value.name}` "
                               f"of type {p.value.type}; a table may depend only on `Float`, "
                               "`Int` and `Bool` parameters", fn.loc)
    wrapper.params = [p for p in wrapper.params if isinstance(p.value.type, ScalarType)]
    # run once per scene: the quick tier's O0 and fast instruction selection (0.45 and 0.39 s
    # for a rough plastic's two tables against O1's 0.58 and 0.61; their runs take 0.08 s
    # rather than 0.05); the host's vectors, since a table's
    # points (a sum table's terms) are independent lanes
    build = Build.of(TABLE_TARGET, "rgb")
    run_passes(sub, pipeline(build), verify=False)
    mod, tm = optimized_module(sub, build.target, speed=0, quick=True)
    t = build.target
    lib = load_native(mod, tm, f"{t.triple} {t.cpu} {t.features}", f"table `{fn.name}`")
    symbol = "rdsl_" + c_name(wrapper.name)
    address = address_of(lib, symbol)
    if not address:
        raise CompileError(f"table `{fn.name}`: the compiled library lacks its kernel", fn.loc)
    compiled = sub.functions[wrapper.name]
    defaults = {p.value.name: p.default for p in wrapper.params if p.uniform}
    return _Kernel(fn.name, lib, symbol, address, c_args(compiled), defaults, used_names)


def _wrapper(sub: Module, fn: Function, has_x: bool) -> Function:
    """``tabulate(x, p...) -> fn([x,] p...)``, exported; ``p`` are ``fn``'s plugin
    parameters (uniform), ``x`` the sample point (varying)."""
    x = Param(Value(fn.params[0].value.type if has_x else F32, "x"))
    rest = fn.params[1:] if has_x else fn.params
    params = [Param(Value(p.value.type, p.value.name), True, p.default) for p in rest]
    wrapper = Function("tabulate", [x, *params], [F32], _body(fn, x, params, has_x), fn.loc,
                       {"export": True})
    return sub.add(wrapper)


def _body(fn: Function, x: Param, params: list[Param], has_x: bool) -> Any:
    from .ir import Block

    body = Block()
    b = Builder(body, fn.loc)
    args = ([x.value] if has_x else []) + [p.value for p in params]
    call = b.emit(Op.CALL, args, [F32], {"callee": fn.name})
    b.return_(call.result)
    return body


def build_read(fn: Function, buf: Value | None, values: list[float] | None) -> None:
    """Replace the body of the read function ``fn`` (``NAME.read``, see dsl/lower.py) by the
    lookup of its table at the offset in its hidden parameter: in ``buf`` (the generic
    build's ``PRM``, a parameter of ``fn``), or in a ``table`` constant of ``values``.
    Linear interpolation as Mitsuba's ``lerp_gather``: ``t = (x - lo) (n - 1) / (hi - lo)``,
    ``i = clamp(int(t), 0, n - 2)``, ``(1 - w) v[i] + w v[i + 1]`` with ``w = t - i``
    (extrapolating linearly outside ``lo..hi``)."""
    from .ir import Block

    opts = fn.attrs["table"]
    body = Block()
    b = Builder(body, fn.loc)
    if buf is None:
        buf = b.op(Op.TABLE, BufferType(F32), values=list(values or []))
    offset = next(p.value for p in fn.params if p.value.name == opts["slot"])
    if "n" not in opts:
        b.return_(b.op(Op.LOAD, F32, buf, offset))
        fn.body = body
        return
    n, lo, hi = opts["n"], opts["lo"], opts["hi"]
    x = fn.params[0].value
    t = b.op(Op.MUL, F32, b.op(Op.SUB, F32, x, b.const(lo, F32)),
             b.const(float(np.float32((n - 1) / (hi - lo))), F32))
    i = b.op(Op.CAST, I32, t)
    i = b.op(Op.MIN, I32, b.op(Op.MAX, I32, i, b.const(0, I32)), b.const(n - 2, I32))
    w1 = b.op(Op.SUB, F32, t, b.op(Op.CAST, F32, i))
    w0 = b.op(Op.SUB, F32, b.const(1.0, F32), w1)
    at = b.op(Op.ADD, I32, offset, i)
    v0 = b.op(Op.LOAD, F32, buf, at)
    v1 = b.op(Op.LOAD, F32, buf, b.op(Op.ADD, I32, at, b.const(1, I32)))
    b.return_(b.op(Op.ADD, F32, b.op(Op.MUL, F32, w0, v0), b.op(Op.MUL, F32, w1, v1)))
    fn.body = body
