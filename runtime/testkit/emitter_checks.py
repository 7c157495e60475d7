"""The checks of an emitter plugin: its radiance (eval) is finite and never negative, for
every direction (grazing ones included), at points across the uv square, for the given
parameters and at extreme values of each; and the chi-square of its direction sampling
where the plugin has one.

rdsl's emitter interface is ``eval(si)`` alone: the renderer samples area lights by
choosing points uniformly on their shape (stdlib/render/lights.rdsl), so an emitter plugin
has no direction sampling of its own, and that row says so (SKIP).  The chi-square of the
shapes' sampling is the renderer's (tests/test_emitter_sampling.py).
"""

from __future__ import annotations

import numpy as np

from .common import Options, finite_rows, rng, sphere_sweep, surface
from .harness import Harness
from .report import SKIP, Row

f32 = np.float32


def _radiance_bad(h: Harness, params: dict, n: int = 1024) -> str:
    wi = sphere_sweep(n, h.name)
    uv = rng("emitter-uv", h.name).uniform(-0.5, 1.5, (n, 2)).astype(f32)
    le = np.asarray(h.emitted(surface(wi, uv), **params))
    if not np.all(np.isfinite(le)):
        return "eval() is NaN or infinite"
    if np.any(le < 0):
        return "eval() is negative"
    return ""


def check_emitter(h: Harness, opts: Options) -> list[Row]:
    """Every check of the emitter ``h``, as table rows."""
    rows = finite_rows(h.decl, opts, lambda p: _radiance_bad(h, p),
                       "1024 directions and uv")
    rows.append(Row("chi2 direction sampling", "-", "-", f"p > {opts.p_min:g}", SKIP,
                    "rdsl's emitter interface is eval() alone: the renderer samples an "
                    "area light's shape, not the plugin"))
    return rows
