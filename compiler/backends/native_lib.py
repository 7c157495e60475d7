"""Host code compiled by LLVM and loaded into this process as a shared library.

Kernels that the compiler itself runs (the run-once table kernels of
compiler/precompute.py, the Embree user-geometry callbacks of llvm_shapes.py) go through
the same path as every other kernel: an object file from the target machine, linked with
``cc -shared`` and loaded with ctypes.  (They used LLVM's MCJIT before; a test worker
died inside MCJIT in 2 of 3 full-suite runs, in a process that also loads many linked
kernel libraries.)  The library is cached under ``$RDSL_CACHE_DIR/native``, keyed by a
hash of the optimized LLVM IR and the target machine, so a scene loaded again links
nothing."""

from __future__ import annotations

import ctypes
import hashlib
import os
import tempfile
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
    text = str(mod)
    key = hashlib.sha256("\0".join((text, machine, str(tm.target_data))).encode()
                         ).hexdigest()[:32]
    lib = _loaded.get(key)
    if lib is not None:
        return lib
    root = cache_dir() / "native"
    so = root / f"{key}.so"
    if not so.is_file():
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
