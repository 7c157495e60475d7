"""Host code compiled by LLVM and loaded into this process as a shared library.

Kernels that the compiler itself runs (the run-once table kernels of
compiler/precompute.py, the Embree user-geometry callbacks of llvm_shapes.py) go through
the same path as every other kernel: an object file from the target machine, linked with
``cc -shared`` and loaded with ctypes.  (They used LLVM's MCJIT before; a test worker
died inside MCJIT in 2 of 3 full-suite runs, in a process that also loads many linked
kernel libraries.)  The library is cached under ``$RDSL_CACHE_DIR/native``, keyed by a
hash of the optimized LLVM IR and the target machine, so a scene loaded again links
nothing; or (:func:`load_native_from`) by a hash of what decides that IR, LLVM's version,
the machine and the compiler's code, so that a process finding the library builds and
optimizes no IR either (the Embree callbacks' took 0.2 s of every scene load with a sphere
or a disk)."""

from __future__ import annotations

import ctypes
import hashlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...core.cachedir import cache_dir
from ..diagnostics import CompileError
from .clib import link_shared

_loaded: dict[str, ctypes.CDLL] = {}  # kept for the process: the code must stay mapped


def load_native(mod: Any, tm: Any, machine: str, what: str) -> ctypes.CDLL:
    """Link the optimized llvmlite ModuleRef ``mod`` for target machine ``tm`` into a
    shared library (or find it in the cache) and load it; ``machine`` describes what ``tm``
    was created for (CPU and features: part of the cache key), ``what`` names the code in
    errors."""
    return _load(_key(str(mod), machine, str(tm.target_data)), lambda: (mod, tm), what)


def load_native_from(source: str, machine: str, what: str,
                     build: Callable[[], tuple[Any, Any]]) -> ctypes.CDLL:
    """:func:`load_native` of ``build()`` (the optimized ModuleRef and its target machine),
    keyed by ``source``, which with LLVM's version, ``machine`` (triple, CPU and features)
    and the compiler's code (how ``build`` generates and optimizes) decides what ``build``
    returns (the text of the IR it parses, or a name for IR the compiler's code alone
    generates): ``build`` runs only when the library is in neither this process nor the
    cache."""
    import llvmlite.binding as llvm

    from ...core.cachedir import compiler_fingerprint

    return _load(_key(source, machine, llvm.get_default_triple(), compiler_fingerprint(),
                      ".".join(map(str, llvm.llvm_version_info))), build, what)


def _key(*parts: str) -> str:
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:32]


def _load(key: str, build: Callable[[], tuple[Any, Any]], what: str) -> ctypes.CDLL:
    lib = _loaded.get(key)
    if lib is not None:
        return lib
    root = cache_dir() / "native"
    so = root / f"{key}.so"
    if not so.is_file():
        mod, tm = build()
        obj = tm.emit_object(mod)
        try:
            root.mkdir(parents=True, exist_ok=True)
            link_shared(obj, so)
        except OSError:  # no writable cache: a private temporary library
            tmp = Path(tempfile.mkdtemp(prefix="rdsl-native-"))
            so = tmp / f"{key}.so"
            link_shared(obj, so)
    try:
        lib = ctypes.CDLL(os.fspath(so))
    except OSError as e:
        raise CompileError(f"{what}: cannot load the compiled library `{so}`: {e}") from None
    _loaded[key] = lib
    return lib


def address_of(lib: ctypes.CDLL, symbol: str) -> int:
    """The address of ``symbol`` in ``lib``, 0 when it is missing."""
    try:
        return ctypes.cast(getattr(lib, symbol), ctypes.c_void_p).value or 0
    except AttributeError:
        return 0
