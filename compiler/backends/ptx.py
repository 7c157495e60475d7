"""CUDA PTX through LLVM's NVPTX backend: ``rdsl compile FILE --target ptx --arch sm_80``.

The IR is lowered by the LLVM backend (``llvm.py``, the same body functions as the CPU's) at
width 1; ``ptx_entry.py`` wraps each kernel in a ``ptx_kernel`` entry that maps CUDA threads
to elements.  LLVM's O3 pipeline and its NVPTX code generator produce the PTX text, whose
floating-point arithmetic keeps the IR's semantics: every ``add``/``sub``/``mul`` carries the
explicit ``.rn`` rounding that keeps ``ptxas`` from fusing it into an FMA, ``div`` and
``sqrt`` are the IEEE ``.rn`` forms, and denormals are kept (no ``.ftz``).  The IR's math has
no transcendental intrinsic (``sin``, ``exp``, ``pow``... are polynomials in
``stdlib/math.rdsl``); ``sqrt``, ``floor``, ``ceil`` and ``fabs`` map to PTX instructions,
so no libdevice is needed.

A build writes ``STEM.ptx`` and the CPU build's manifest ``STEM.json`` (with ``arch``): the
kernels' arguments are those of the C ABI (``base.c_params``), arrays as global pointers.
:func:`find_ptxas` and :func:`run_ptxas` check the PTX with NVIDIA's assembler when one is
installed (the CUDA toolkit's, or the ``nvidia-cuda-nvcc-cu12`` wheel's).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from .. import ir
from ..diagnostics import CompileError
from ..targets import Target, get_target
from .base import Backend

PTXAS_HINT = ("install the CUDA toolkit (Debian: nvidia-cuda-toolkit) or "
              "`pip install nvidia-cuda-nvcc-cu12`")


class PTXBackend(Backend):
    """CUDA PTX through LLVM's NVPTX backend: one lane per thread."""

    name = "ptx"
    emits = ("ptx",)
    supports_gather = True
    supports_scatter = True
    supports_float_rem = True
    max_width = 1
    widths = (1,)


def emit_ptx(module: ir.Module, target: Target | str = "ptx") -> str:
    """The PTX text of ``module`` (vectorized at width 1) for ``target`` (a ptx target)."""
    from .llvm import emit_asm

    t = get_target(target)
    if t.backend != "ptx":
        raise CompileError(f"emit_ptx needs a ptx target, not `{t.name}`")
    return emit_asm(module, t)


def build_ptx(module: ir.Module, target: Target, out_dir: str | os.PathLike,
              stem: str) -> dict[str, Path]:
    """Write ``<stem>.ptx`` and the manifest ``<stem>.json`` (target, arch, kernels and their
    C-ABI arguments) into ``out_dir``; returns ``{"ptx": path, "manifest": path}``."""
    from .clib import manifest, writable_dir

    out = writable_dir(out_dir)
    paths = {"ptx": out / f"{stem}.ptx", "manifest": out / f"{stem}.json"}
    text = emit_ptx(module, target)
    man = dict(manifest(module, target), arch=target.cpu, load="cuModuleLoadData")
    for k in man["kernels"]:
        del k["range_symbol"]  # one entry point per kernel on the GPU
    try:
        paths["ptx"].write_text(text)
        paths["manifest"].write_text(json.dumps(man, indent=1) + "\n")
    except OSError as e:
        raise CompileError(f"cannot write `{e.filename or out}`: {e.strerror or e}") from None
    return paths


# --------------------------------------------------------------------------------------
# ptxas


def _wheel_ptxas() -> list[Path]:
    """ptxas of the ``nvidia-cuda-nvcc`` wheels installed beside this Python."""
    found = []
    for entry in sys.path:
        p = Path(entry) / "nvidia" / "cuda_nvcc" / "bin" / "ptxas"
        if p.is_file() and os.access(p, os.X_OK):
            found.append(p)
    return found


def ptxas_candidates() -> list[Path]:
    """Every ptxas found: ``$RDSL_PTXAS``, the one on PATH, the CUDA toolkit's, the wheels'."""
    out: list[Path] = []
    for c in (os.environ.get("RDSL_PTXAS"), shutil.which("ptxas"),
              "/usr/local/cuda/bin/ptxas", *_wheel_ptxas()):
        if c and Path(c).is_file() and Path(c).resolve() not in [p.resolve() for p in out]:
            out.append(Path(c))
    return out


def ptxas_archs(ptxas: Path) -> set[str]:
    """The ``sm_XY`` names ``ptxas --help`` lists as allowed GPU names."""
    r = subprocess.run([str(ptxas), "--help"], check=False, capture_output=True, text=True,
                       timeout=60)
    return set(re.findall(r"'(sm_\d+[a-z]?)'", r.stdout))


def find_ptxas(arch: str) -> Path | None:
    """A ptxas that assembles for ``arch`` (CUDA 13 dropped sm_70; CUDA 12's has it)."""
    for p in ptxas_candidates():
        if arch in ptxas_archs(p):
            return p
    return None


def run_ptxas(ptx: str, arch: str, ptxas: Path | None = None) -> str:
    """Assemble ``ptx`` for GPU ``arch`` (``sm_XY``: that of the PTX's ``.target`` or a
    newer one) with ptxas (``-v``: registers, spills); returns its report, or raises a
    CompileError with ptxas's message."""
    if not re.fullmatch(r"sm_\d+[a-z]?", arch):
        raise CompileError(f"`{arch}` is not a GPU name (sm_XY)")
    exe = ptxas or find_ptxas(arch)
    if exe is None:
        raise CompileError(f"no ptxas that assembles for {arch} was found: {PTXAS_HINT}")
    with tempfile.TemporaryDirectory(prefix="rdsl-ptxas-") as tmp:
        src = Path(tmp) / "k.ptx"
        src.write_text(ptx)
        r = subprocess.run([str(exe), "--gpu-name", arch, "-v", str(src), "-o",
                            str(Path(tmp) / "k.cubin")], check=False, capture_output=True,
                           text=True, timeout=600)
    if r.returncode != 0:
        raise CompileError(f"ptxas ({exe}) rejected the PTX for {arch}:\n{r.stderr.strip()}")
    return r.stderr + r.stdout
