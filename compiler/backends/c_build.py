"""Builds of the SIMD C target: ``<stem>.c`` and ``<stem>.h`` (the source a user compiles
into their own program), and, unless only the source is asked for, ``<stem>.so`` compiled
by the machine's ``cc`` plus the ``<stem>.json`` manifest that ``rdsl.load`` reads, the same
loader and C ABI as the LLVM targets' libraries."""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path

from .. import ir
from ..diagnostics import CompileError
from ..targets import Target
from .c import emit_c
from .clib import _cc, header, manifest, run_cc, writable_dir

# -std=c11: vector extensions are accepted in ISO mode and GCC does not contract a*b+c
# into FMA there; -ffp-contract=off says so for any compiler (the IR's semantics are exact)
CFLAGS = ("-std=c11", "-O2", "-march=native", "-ffp-contract=off", "-fPIC")


def cflags() -> tuple[str, ...]:
    """:data:`CFLAGS` and then the words of ``$RDSL_CFLAGS`` (``RDSL_CFLAGS=-O3``: a later
    ``-O``/``-march`` wins; the kernel cache keys them, rdsl.runtime.api)."""
    return CFLAGS + tuple(shlex.split(os.environ.get("RDSL_CFLAGS", "")))


def compile_shared(c_path: Path, so_path: Path, flags: tuple[str, ...] | None = None) -> None:
    """``cc FLAGS -shared c_path -lm -o so_path`` (``flags``: default :func:`cflags`)."""
    flags = cflags() if flags is None else flags
    cc = _cc()
    run_cc(cc, [*flags, "-shared", str(c_path), "-lm"], so_path,
           f"compiling {c_path.name} with `{cc} {' '.join(flags)}`")


def build_c_library(module: ir.Module, target: Target, out_dir: str | os.PathLike,
                    stem: str, source_only: bool = False) -> dict[str, Path]:
    """Write ``<stem>.c``, ``<stem>.h`` and ``<stem>.json``, and compile ``<stem>.so``
    unless ``source_only``.  Returns the paths by kind (c, header, manifest, so)."""
    out = writable_dir(out_dir)
    if module.attrs.get("width", 1) != target.width:
        raise CompileError(f"module was vectorized for width {module.attrs.get('width', 1)} "
                           f"but target `c` was asked for width {target.width}")
    paths = {"c": out / f"{stem}.c", "header": out / f"{stem}.h",
             "manifest": out / f"{stem}.json"}
    if not source_only:
        paths["so"] = out / f"{stem}.so"
    for p in paths.values():
        if p.exists() and not p.is_file():
            raise CompileError(f"cannot write `{p}`: it exists and is not a regular file")
    source = emit_c(module, stem)
    man = manifest(module, target)
    man["cflags"] = list(cflags())
    try:
        paths["c"].write_text(source)
        paths["header"].write_text(header(module, target, stem))
        if not source_only:
            compile_shared(paths["c"], paths["so"])
        paths["manifest"].write_text(json.dumps(man, indent=1) + "\n")
    except OSError as e:
        raise CompileError(f"cannot write `{e.filename or out}`: {e.strerror or e}") from None
    return paths
