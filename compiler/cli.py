"""The compiler's subcommands of the ``rdsl`` command line: ``check``, ``ir`` and ``compile``.

:func:`add_commands` declares them on the top-level parser of ``rdsl/cli.py``, which adds the
runtime's ``render`` and turns a :class:`CompileError` raised here into diagnostics and exit
status 1 (a user mistake never shows a traceback).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from ..core.color import VARIANTS
from .diagnostics import CompileError

Command = Callable[[argparse.Namespace], int]

_VARIANTS_HELP = ", ".join(VARIANTS) + " (default: rgb)"
_AD_HELP = ("differentiate: 'forward' gives each kernel with Float arguments a tangent "
            "argument per argument and a tangent result per Float result; 'reverse' an adjoint "
            "argument per Float result and a gradient result per Float argument (docs/ad.md)")
_ELIM_HELP = ("reverse mode: run graph elimination (the `eliminate` pass) with this "
              "threshold on d_in*d_out (bare flag: 10; 0: off); implied by "
              "--print-after eliminate (docs/ad.md)")
_ARCH_HELP = "GPU architecture of target ptx: sm_70 (default), sm_80 or sm_90"
_WIDTH_HELP = ("SIMD width of target c, or the lanes per work-item of target opencl: 1, 4, "
               "8 or 16 (default: the host's widest); the LLVM targets have their own")


def add_commands(sub: argparse._SubParsersAction) -> dict[str, Command]:
    """Add ``check``, ``ir`` and ``compile`` to ``sub``; returns their handlers by name."""
    c = sub.add_parser("check", help="parse and type-check a .rdsl file")
    c.add_argument("file")

    i = sub.add_parser("ir", help="print the IR, after any pass")
    i.add_argument("file")
    i.add_argument("--variant", default="rgb", help=_VARIANTS_HELP)
    i.add_argument("--target", default="host")
    i.add_argument("--width", type=int, default=None, help=_WIDTH_HELP)
    i.add_argument("--print-after", default=None, metavar="PASS",
                   help="print after every run of PASS ('lower' for the frontend's IR, "
                        "'all' for every pass); default: the final IR")
    i.add_argument("--no-locs", action="store_true", help="omit source locations")
    i.add_argument("--ad", choices=["forward", "reverse"], default=None, help=_AD_HELP)
    i.add_argument("--eliminate", type=int, nargs="?", const=10, default=None,
                   metavar="THRESHOLD", help=_ELIM_HELP)

    k = sub.add_parser("compile", help="compile to a shared library, C header and manifest")
    k.add_argument("file")
    k.add_argument("--target", default="host",
                   help="scalar, sse4, avx2, avx512, host (default), c (SIMD C source "
                        "compiled by the machine's cc), opencl (STEM.cl: OpenCL C, built "
                        "by the OpenCL driver when loaded), ptx (CUDA PTX: STEM.ptx), or "
                        "spirv (GLSL compute shaders STEM.comp, SPIR-V STEM.spv for Vulkan)")
    k.add_argument("--width", type=int, default=None, help=_WIDTH_HELP)
    k.add_argument("--arch", default=None, help=_ARCH_HELP)
    k.add_argument("--variant", default="rgb", help=_VARIANTS_HELP)
    k.add_argument("-o", "--output", default=None,
                   help="output stem: writes STEM.so, STEM.h and STEM.json "
                        "(default: the source's name in the current folder)")
    k.add_argument("--emit", choices=["lib", "llvm", "asm", "obj", "c"], default="lib",
                   help="what to produce; llvm/asm go to stdout unless -o is given; "
                        "c (target c): only STEM.c, STEM.h and STEM.json, no cc needed")
    k.add_argument("--ad", choices=["forward", "reverse"], default=None, help=_AD_HELP)
    return {"check": _check, "ir": _ir, "compile": _compile}


def _require_file(path: str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise CompileError(f"{path}: no such file")
    return p


def _check(args: argparse.Namespace) -> int:
    from ..dsl import check

    check(_require_file(args.file))
    print(f"{args.file}: ok")
    return 0


def _ir(args: argparse.Namespace) -> int:
    from .build import Build
    from .driver import frontend, pipeline, run_passes
    from .passes import pass_names
    from .printer import print_module

    elim = args.eliminate
    if args.print_after == "eliminate" and args.ad != "reverse":
        raise CompileError("`eliminate` runs in a reverse build: add --ad reverse")
    if elim is None and args.print_after == "eliminate":
        elim = 10
    build = Build.of(args.target, args.variant, args.width, args.ad, elim or 0)
    names = pass_names() + ["lower", "all"]
    if args.print_after is not None and args.print_after not in names:
        raise CompileError(f"unknown pass `{args.print_after}` (expected one of: "
                           f"{', '.join(names)})")
    module = frontend(_require_file(args.file))
    if args.print_after in ("lower", "all"):
        print("// ----- after lower -----")
        print(print_module(module, locs=not args.no_locs), end="")
    if args.print_after == "lower":
        return 0
    out = _LocFilter(sys.stdout) if args.no_locs else sys.stdout
    run_passes(module, pipeline(build), print_after=args.print_after,
               out=out)
    if args.print_after is None:
        print(print_module(module, locs=not args.no_locs), end="")
    return 0


class _LocFilter:
    """Strips ` loc(...)` suffixes from printed IR."""

    def __init__(self, stream) -> None:
        self.stream = stream

    def write(self, text: str) -> None:
        import re

        self.stream.write(re.sub(r" +loc\([^)]*\)", "", text))


def _compile(args: argparse.Namespace) -> int:
    from .backends.clib import build_library
    from .backends.llvm import emit_asm, emit_llvm, emit_object
    from .build import Build
    from .driver import compile_kernels

    build = Build.of(_target(args), args.variant, args.width, args.ad)
    tgt = build.target
    if tgt.backend == "ptx" and args.emit == "obj":
        raise CompileError("--emit obj needs a CPU target; target ptx writes PTX text "
                           "(--emit lib or asm)")
    llvm_like = tgt.backend in ("llvm", "ptx")  # LLVM IR and assembly exist for these
    if args.emit != "lib" and not (tgt.backend == "c" if args.emit == "c" else llvm_like):
        other = "c or lib" if tgt.backend == "c" else "lib"
        raise CompileError(f"--emit {args.emit} needs " + ("--target c" if args.emit == "c"
                           else f"an LLVM target, not `{tgt.name}` (use --emit {other})"))
    src = _require_file(args.file).resolve()
    module, _ = compile_kernels(src, build)
    if args.emit in ("llvm", "asm", "obj"):
        data = {"llvm": lambda: emit_llvm(module, tgt), "asm": lambda: emit_asm(module, tgt),
                "obj": lambda: emit_object(module, tgt)}[args.emit]()
        if args.output is None and args.emit != "obj":
            sys.stdout.write(data)
            return 0
        ext = {"llvm": ".ll", "asm": ".s", "obj": ".o"}[args.emit]
        out = Path(args.output) if args.output else Path(src.stem + ext)
        _refuse_input(out, src)
        _write(out, data)
        print(f"wrote {out}")
        return 0
    stem = Path(args.output) if args.output else Path(src.stem)
    if stem.suffix in (".so", ".h", ".json", ".c", ".cl", ".ptx", ".comp", ".spv"):
        stem = stem.with_suffix("")
    for ext in (".so", ".h", ".json", ".c", ".cl", ".ptx", ".comp", ".spv"):
        _refuse_input(stem.with_suffix(ext) if stem.suffix == "" else
                      Path(str(stem) + ext), src)
    out_dir = stem.parent if str(stem.parent) else Path(".")
    if args.emit == "c":
        from .backends.c_build import build_c_library

        paths = build_c_library(module, tgt, out_dir, stem.name, source_only=True)
    elif tgt.backend == "ptx":
        from .backends.ptx import build_ptx

        paths = build_ptx(module, tgt, out_dir, stem.name)
    else:
        paths = build_library(module, tgt, out_dir, stem.name)
    for p in paths.values() if isinstance(paths, dict) else paths:
        print(f"wrote {p}")
    return 0


def _target(args: argparse.Namespace):
    """The target name, or the ptx target of ``--arch`` (which needs ``--target ptx``)."""
    if args.arch is None:
        return args.target
    if args.target != "ptx":
        raise CompileError(f"--arch picks the GPU architecture of target ptx, not of "
                           f"`{args.target}`")
    from .targets import ptx_target

    return ptx_target(args.arch)


def _refuse_input(out: Path, src: Path) -> None:
    if out.resolve() == src:
        raise CompileError(f"{out}: refusing to overwrite the input file")


def _write(path: Path, data: str | bytes) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data)
    except OSError as e:
        raise CompileError(f"{path}: cannot write output: {e.strerror}") from e
