"""The checks of a texture plugin: its range.  ``eval`` (a colour; its intensity in
polarized variants) and, where the plugin has it, ``eval_1`` (the one value a Float
parameter reads) over uv in and far outside the unit square, at the given parameters and
with each at an extreme value: finite and never negative, the range printed."""

from __future__ import annotations

import numpy as np

from .common import Options, finite_rows, rng, surface
from .harness import Harness
from .report import Row, verdict

f32 = np.float32


def _uvs(name: str, n: int = 4096) -> np.ndarray:
    """uv points: a random spread over [-2, 3]^2, the unit square's corners and edges, and
    coordinates far away (tiling textures must wrap, not overflow)."""
    gen = rng("texture-uv", name)
    special = [[0, 0], [1, 1], [0.5, 0.5], [1, 0], [0, 1], [-1e-7, 1 + 1e-7],
               [1e6, -1e6], [-3.5e7, 2.5e7], [123.456, -789.01]]
    return np.concatenate([gen.uniform(-2, 3, (n - len(special), 2)), special]).astype(f32)


def _values(h: Harness, params: dict, one: bool) -> np.ndarray:
    uv = _uvs(h.name)
    wi = np.tile(np.array([0, 0, 1], f32), (len(uv), 1))
    return np.asarray(h.texture(surface(wi, uv), one=one, **params), np.float64)


def _bad(h: Harness, params: dict, one: bool) -> str:
    v = _values(h, params, one)
    what = "eval_1()" if one else "eval()"
    if not np.all(np.isfinite(v)):
        return f"{what} is NaN or infinite"
    return f"{what} is negative" if np.any(v < 0) else ""


def check_texture(h: Harness, opts: Options) -> list[Row]:
    """Every check of the texture ``h``, as table rows."""
    rows = []
    for one in (False, True) if "eval_1" in h.decl.methods else (False,):
        v = _values(h, opts.params, one)
        ok = bool(np.all(np.isfinite(v)) and np.all(v >= 0))
        rows.append(Row("range", "eval_1" if one else "eval",
                        f"{np.nanmin(v):.4g} .. {np.nanmax(v):.4g}", "finite, >= 0",
                        verdict(ok), "" if ok else _bad(h, opts.params, one)))
        rows += [Row(r.check, f"{r.case} ({'eval_1' if one else 'eval'})", r.value,
                     r.threshold, r.status, r.note)
                 for r in finite_rows(h.decl, opts, lambda p, o=one: _bad(h, p, o),
                                      f"{len(_uvs(h.name))} uv")
                 if r.case == "extreme params"]  # (the given ones: the range row)
    return rows
