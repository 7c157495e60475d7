"""The compiler driver: source -> IR -> passes -> kernels.

The pipeline reads top to bottom; each entry says what it is for.  Errors raised inside a
pass keep their user-facing diagnostic; anything else is reported as an internal compiler
error naming the pass.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

from ..core.gcpause import gc_paused
from ..core.scene_spec import SceneSpec
from .build import Build
from .diagnostics import CompileError, InternalError  # noqa: F401 (InternalError re-exported)
from .ir import Module, clone_function
from .passes import Pass
from .passes.ad_forward import AdForward
from .passes.ad_reverse import AdReverse
from .passes.eliminate import Eliminate
from .passes.evaluate import Evaluate, evaluable
from .passes.inline import Inline
from .passes.lift import Lift
from .passes.optimize import Optimize
from .passes.scalarize import Scalarize
from .passes.specialize import Specialize
from .passes.tape_stores import TapeStores
from .passes.vectorize import Vectorize
from .sources import PRELUDE, STDLIB, is_path, source_files  # noqa: F401 (re-exported)


def pipeline(build: Build, scene: SceneSpec | None = None,
             report: list[str] | None = None) -> list[Pass]:
    """The passes from lowered IR to vectorized scalar IR for ``build``, in order."""
    return [
        *([Specialize(scene, report)] if scene is not None else []),  # the scene's instances
        Inline(build.ad is not None, keep=evaluable),  # calls become bodies, but pure calls
        # running loops
        Optimize(),  # fold and prune early: what the scene fixes becomes constants
        Evaluate(report=report),  # pure calls with constant arguments: run once, now
        Inline(build.ad is not None),  # the calls left become bodies; recursion is a diagnostic
        Optimize(),  # fold the evaluated constants through
        Lift(build.model, build.ad is not None),  # Spectrum becomes mono/rgb/...; `if const`
        # traits become constants
        Optimize(),  # fold the trait branches away
        Scalarize(),  # aggregates become scalars; kernel ABI recorded
        Optimize(),  # forward extracts, CSE the leaves
        # tangents (forward mode), adjoints (reverse), or derivative() = 0 without AD
        AdReverse(build.tape, build.seeds, build.tape_covers) if build.ad == "reverse"
        else AdForward(build.ad),
        # reverse mode, if asked: the sweeps read eliminated edge weights, not primal values
        *([Eliminate(build.eliminate)] if build.eliminate else []),
        # the adjoint sweeps' zero adjoints and repeated partials, pruned before vectorize
        # copies each of them for the lanes (it was half of what vectorize emitted)
        *([Optimize()] if build.ad == "reverse" else []),
        # the tape values no sweep reads are not stored (their loads were pruned above)
        *([TapeStores()] if build.ad == "reverse" else []),
        Vectorize(build.width),  # SPMD over lanes with masks
        Optimize(),  # CSE broadcasts and masks
    ]


def run_passes(module: Module, passes: list[Pass], verify: bool | str = True,
               print_after: str | None = None, out: TextIO = sys.stdout,
               stop_after: str | None = None) -> Module:
    """Run ``passes`` in order, printing where asked.  ``verify``: True (or "each")
    verifies the IR after lowering and after every pass; "ends" after lowering and after
    the last pass only (what renders use: every pass's output is checked by the tests,
    and a fifth of a cold compile went to re-verifying); False never.  Python's cycle
    collector is paused meanwhile (:func:`~rdsl.core.gcpause.gc_paused`: the passes allocate
    hundreds of thousands of objects and leave no cycles), for every caller: a table's
    kernel (compiler/precompute.py), ``rdsl ir`` and the tests call this directly, and
    with the collector running a rough plastic's adjoint took 1.8x as long."""
    with gc_paused():
        return _run_passes(module, passes, verify, print_after, out, stop_after)


def _run_passes(module: Module, passes: list[Pass], verify: bool | str,
                print_after: str | None, out: TextIO, stop_after: str | None) -> Module:
    from .printer import print_module
    from .verify import verify as verify_module

    if verify:
        _guard("lower", lambda: verify_module(module))
    for k, p in enumerate(passes):
        _guard(p.name, lambda p=p: p.run(module))
        last = k == len(passes) - 1 or stop_after == p.name
        if verify is True or verify == "each" or (verify == "ends" and last):
            _guard(p.name, lambda: verify_module(module))
        if print_after in (p.name, "all"):
            out.write(f"// ----- after {p.name} -----\n")
            out.write(print_module(module))
        if stop_after == p.name:
            break
    return module


def _guard(name: str, fn: Callable[[], object]) -> None:
    try:
        fn()
    except CompileError:
        raise
    except RecursionError as e:
        raise CompileError(f"program too deeply nested (in pass `{name}`)") from e
    except Exception as e:  # a compiler bug: say where it happened
        raise InternalError(f"internal compiler error in pass `{name}`: "
                            f"{type(e).__name__}: {e}") from e


def frontend(source_or_path: str | Path, filename: str | None = None,
             search_paths: list[Path] | None = None) -> Module:
    """Parse, check and lower a program to IR; ``search_paths``: folders its imports are
    looked up in after the importing file's own (user plugin folders)."""
    from ..dsl import compile_to_ir

    try:
        return compile_to_ir(source_or_path, filename=filename, search_paths=search_paths)
    except CompileError:
        raise
    except RecursionError as e:
        raise CompileError("program too deeply nested") from e


# The IR of a program as the frontend lowered it (before any pass), kept by compile_kernels
# for programs with `table` functions (their `.read`s carry attrs["table"]): a generic
# build's tables are filled after its compile from the plugins' IR (runtime/tables.py),
# which would otherwise be lowered a second time (0.2-0.5 s).  The last two programs.
_LOWERED: dict[tuple[str, str | None, tuple[str, ...]], Module] = {}


def _lowered_key(source_or_path: str | Path, filename: str | None,
                 search_paths: Sequence[Path] | None) -> tuple[str, str | None, tuple[str, ...]]:
    text = Path(source_or_path).read_text() if is_path(source_or_path) else str(source_or_path)
    return text, filename, tuple(str(p) for p in search_paths or ())


def lowered(source_or_path: str | Path, filename: str | None = None,
            search_paths: Sequence[Path] | None = None) -> Module:
    """The frontend's IR of the program (:func:`frontend`), shared: the caller must not
    change it (clone what it rewrites); the one a compile in this process lowered, if it
    kept it."""
    key = _lowered_key(source_or_path, filename, search_paths)
    module = _LOWERED.get(key)
    if module is None:
        module = frontend(source_or_path, filename, list(search_paths or []) or None)
    return module


def _keep_lowered(module: Module, source_or_path: str | Path, filename: str | None,
                  search_paths: Sequence[Path] | None) -> None:
    if not any("table" in f.attrs for f in module.functions.values()):
        return
    copy = Module(structs=dict(module.structs))
    for f in module.functions.values():
        copy.add(clone_function(f))
    while len(_LOWERED) >= 2:
        _LOWERED.pop(next(iter(_LOWERED)))
    _LOWERED[_lowered_key(source_or_path, filename, search_paths)] = copy


def verify_mode() -> str:
    """How a compile for a render verifies its IR: after lowering and at the end, or after
    every pass when ``RDSL_VERIFY_EACH=1`` (to find which pass broke an invariant)."""
    return "each" if os.environ.get("RDSL_VERIFY_EACH", "") not in ("", "0") else "ends"


def compile_kernels(source_or_path: str | Path, build: Build, filename: str | None = None,
                    scene: SceneSpec | None = None, report: list[str] | None = None,
                    search_paths: list[Path] | None = None,
                    exports: Sequence[str] | None = None) -> tuple[Module, list[Path]]:
    """Compile to post-vectorize IR for ``build``.  Returns the module and the source
    files it was built from (for cache keys).  ``scene`` specializes the scene
    placeholders (see :mod:`rdsl.compiler.passes.specialize`); ``report`` collects what
    specialization did; ``search_paths`` are the frontend's (see :func:`frontend`).
    ``exports``: build only these of the file's kernels (``"roughplastic.eval"``); the
    others, and what only they call, are not compiled."""
    with gc_paused():
        module = frontend(source_or_path, filename, search_paths)
        _keep_lowered(module, source_or_path, filename, search_paths)
        if exports is not None:
            keep_exports(module, exports)
        run_passes(module, pipeline(build, scene, report), verify=verify_mode())
    module.attrs["target"] = build.target.name
    return module, source_files(source_or_path, search_paths or (), filename=filename)


def keep_exports(module: Module, exports: Sequence[str]) -> None:
    """Unexport every kernel not named in ``exports``; a name the file does not export is a
    diagnostic listing those it does."""
    exported = [n for n, f in module.functions.items() if f.attrs.get("export")]
    unknown = sorted(set(exports) - set(exported))
    if unknown:
        raise CompileError(f"no exported function {', '.join(map(repr, unknown))}; the file "
                           f"exports: {', '.join(sorted(exported))}", None)
    for name in exported:
        if name not in exports:
            module.functions[name].attrs.pop("export")

