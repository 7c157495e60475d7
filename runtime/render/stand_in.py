"""The generic build standing in for a small render's specialized kernels.

A specialized kernel folds the scene's parameter values: editing one value in the XML (a
reflectance, a roughness, a light's radiance) makes a new kernel, and a new kernel is a
compile (1.5-2 s on the material preview, more with tables), however small the render.
The generic build reads those values from ``PRM`` at run time; its kernel depends only on
the scene's structure (its plugin types, emitter and shape kinds: what specialization
folds in both builds), so it is shared by every scene of that structure and, once built,
in the kernel cache for all of them.

So a small render (the quick tier's size, ``renderer.QUICK_SAMPLES``) of a scene whose own
kernels are in the cache in neither tier renders with the generic build's kernels when
those are cached (a scene of the same structure was rendered before: the full tier if
there, else the quick tier).  When they are not, the scene's own quick-tier kernels are
compiled as before (the generic build's are 5-50% larger: its first image would come
later), and once it has rendered the generic ones are built in another process, for the
edits to come
(:func:`start_generic_build`, 2-3 s; it goes on after a one-off ``rdsl render`` ends, as
runtime/render/tier_up.py's builds do).  From a
stand-in scene's second render on, its own kernels are built in the background and replace
the stand-in when ready, as the quick tier is replaced; a large render compiles them at
once.  The generic build renders the specialized build's image to float rounding (within
1e-5 absolute; tests/test_generic_build.py and tests/test_stand_in.py), not bit for bit:
functions the specialized build evaluates at compile time on constants (``evaluate``) run
as compiled code here.

Not a stand-in: a scene loaded generic already, a differentiated twin, a scene whose
integers the generic build cannot hold (2**24 or more), a target other than the LLVM CPU
ones, and any render with ``RDSL_GENERIC_FIRST=0`` (the test suite sets it, so that a
test's kernels do not depend on what an earlier test left in the shared cache; the tests
of this file turn it on).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

from ...compiler.diagnostics import CompileError

if TYPE_CHECKING:
    from .renderer import Scene

STAND_IN_ENV = "RDSL_GENERIC_FIRST"


def enabled() -> bool:
    """Whether small renders may use the generic build's kernels (``RDSL_GENERIC_FIRST``)."""
    return os.environ.get(STAND_IN_ENV, "1") not in ("0", "")


def is_stand_in(mod: Any) -> bool:
    """Whether ``mod`` is the generic build standing in for a scene's own kernels."""
    return bool(getattr(mod, "stand_in", False))


def generic_stand_in(scene: Scene, small: bool, src: str, kw: dict[str, Any]) -> Any | None:
    """The generic build's kernels for ``scene`` (specialized; ``small``: for a render the
    quick tier's size; ``src`` and ``kw`` what
    :func:`rdsl.runtime.api.jit` builds its own kernels from), with ``scene.prm`` set to
    their parameters and tables, or None where they should not stand in (see the module's
    docstring)."""
    from ..api import jit, jit_cached

    build = scene.build
    if not (enabled() and small and scene.specialize and build.target.backend == "llvm"
            and build.ad is None and not scene.derivative):
        return None
    if jit_cached(src, **kw) or jit_cached(src, quick=True, **kw):
        return None  # the scene's own kernels are at hand
    try:
        generic, prm = scene.parameter_slots(kw["scene"])
    except CompileError:  # an integer only the specialized build holds
        return None
    options = dict(kw, scene=generic)
    full = jit_cached(src, **options)
    if not (full or jit_cached(src, quick=True, **options)):
        # nothing cached: the scene's own quick kernels come sooner (the generic build's are
        # 5-50% larger); the generic ones are built after its render, for the edits to come
        scene._generic_build = (src, options, scene.scene_spec)
        return None
    mod = jit(src, quick=not full, **options)  # from the cache
    mod.stand_in = True
    from ..tables import fill_tables

    scene.prm = fill_tables(mod, scene.scene_spec, prm, src, kw["filename"],
                            scene.search_paths)
    return mod


def after_render(scene: Scene) -> None:
    """Start the background build of the generic kernels that :func:`generic_stand_in`
    left to be built after the scene's first render (on the second core beside the compile,
    it slowed that compile by up to 20%, and it would take a core from the render)."""
    pending = getattr(scene, "_generic_build", None)
    if pending is not None:
        scene._generic_build = None
        start_generic_build(*pending)


def start_generic_build(src: str, options: dict[str, Any], values: Any) -> Any | None:
    """Build the generic kernels of ``jit(src, **options)`` at the quick tier in another
    process (runtime/render/tier_up.py's :class:`TierUp`, which goes on after this process
    ends and fills the kernel cache), and their tables for the values of ``values`` (the
    scene's SceneSpec: an edit of another value finds them in the cache), unless this process has one such build running
    already or the machine has one core (the build would take the render's).  Returns the
    job, or None; never raises (it is an optimization)."""
    global _building
    from .tier_up import TierUp

    if (os.cpu_count() or 1) < 2 or (_building is not None and not _building.done()):
        return None
    try:
        _building = TierUp(src, options, quick=True, tables_for=values)
    except Exception:  # noqa: BLE001 - no process to spare: the next edit compiles
        _building = None
    return _building


_building: Any = None  # this process's background build of generic kernels, if any


def wait_for_generic_build(src: str, kw: dict[str, Any], quick: bool) -> None:
    """Wait for this process's background build of generic kernels if it builds what
    ``jit(src, quick=quick, **kw)`` asks for (a scene whose parameters were assigned after
    its first render compiles those very kernels), rather than compile them beside it."""
    job = _building
    if job is None or not quick or job.done() or job.source != src:
        return
    try:
        same = job.options == kw
    except Exception:  # noqa: BLE001 - options that do not compare: not the same build
        same = False
    if same:
        job.finish()


def tier_words(mod: Any) -> str:
    """What ``rdsl render --report`` says about the tier of ``mod``."""
    level = "quick tier: LLVM O0" if getattr(mod, "quick", False) else "full tier: LLVM O3"
    if is_stand_in(mod):
        return (f"generic build standing in ({level}; parameters read from PRM at run time) "
                "until the scene's own kernels are built: a small render not cached yet")
    if getattr(mod, "quick", False):
        return f"{level}, for a small render not cached yet"
    return level
