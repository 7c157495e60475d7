"""Speculative compilation of the adjoint kernel while the parameters are being set.

A parameter assigned through ``scene.params[name] = value`` is, most of the time, one that
``scene.backward`` will differentiate next (Mitsuba's ``params[key] = opt[key]`` idiom,
the inverse-rendering loop).  The first assignment compiles the generic render kernels
(parameters read at run time), and the first ``backward`` compiles the adjoint kernel:
two compiles, one after the other, on a machine that has a second core.  So each time the
set of assigned parameters grows, :func:`speculate` starts building, in a background
process (runtime/render/tier_up.py's :class:`TierUp`), the adjoint kernel that
``backward(d_img, params=<the assigned names>)`` would build, while this process goes on
with the generic ones; ``backward`` then waits for that job (``Scene.compile``) and loads
its kernels from the cache instead of compiling them.  The quick tier is built when the
scene's renders are small enough for it (the tier ``backward`` asks for), else the full
one.

A guess that turns out wrong costs nothing but the job's core time: ``backward`` with
other parameters, or other ``eliminate``/``tape`` options, compiles its own kernel as
before, and a job that failed leaves it to do so too.  A job made stale by a further
assignment is stopped.  ``RDSL_PREBUILD=0`` turns speculation off, and a machine with one
core never speculates (the two compiles would share it).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .renderer import Scene

__all__ = ["speculate", "wait_for_speculated"]

PREBUILD_ENV = "RDSL_PREBUILD"


def enabled() -> bool:
    """Whether assignments start speculative builds (more than one core, not turned off)."""
    return os.environ.get(PREBUILD_ENV, "1") not in ("0", "") and (os.cpu_count() or 1) > 1


def speculate(scene: Scene, names: list[str]) -> None:
    """Start building the adjoint kernel of ``scene.backward(..., params=names)`` in the
    background, unless it is built, cached or being built; stop a job for other names.
    Never raises: speculation is not the user's business."""
    if not enabled() or scene.build.target.backend != "llvm":
        return
    from ..api import jit_cached, quick_everywhere
    from .backward import TAPE, tape_covers
    from .differentiable import ad_twin, integrator_names, seeds_of
    from .tier_up import TierUp

    integrators = set(integrator_names(scene))
    names = [n for n in names if n.split(".")[0] not in integrators]  # backward refuses them
    if not names:
        return
    old = getattr(scene, "_speculating", None)
    try:
        twin = ad_twin(scene, "reverse", 0, TAPE, seeds_of(scene, names),
                       tape_covers(scene, TAPE))
        if old is not None and old[0] is twin:
            return  # the same kernel: its job goes on
        job = None
        if twin._module is None:
            src, kw = twin._jit_args()
            quick = twin.quick_fits() or quick_everywhere()
            if not (jit_cached(src, **kw) or (quick and jit_cached(src, quick=True, **kw))):
                job = TierUp(src, kw, quick=quick)
    except Exception:  # noqa: BLE001 - a scene the worker cannot take: backward compiles
        return
    if old is not None:
        old[1].stop()
        old[0]._speculated = None
    twin._speculated = job
    scene._speculating = (twin, job) if job is not None else None


def wait_for_speculated(twin: Any, quick: bool) -> None:
    """Wait for the background build of ``twin``'s kernels, if one was started and builds
    a tier that a compile asking for ``quick`` would use: its kernels are then in the cache
    (or, if it failed, the caller compiles them).  A quick-tier job when the full tier is
    asked for is stopped."""
    job = getattr(twin, "_speculated", None)
    if job is None:
        return
    twin._speculated = None
    if job.quick and not quick:
        job.stop()
    else:
        job.finish()
