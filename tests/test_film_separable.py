"""The renderer's separable film path (axis weights computed once per sample) gives the
same image as the direct gather `film_accumulate`, for every filter."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.runtime.render.film import film_reach, new_accumulator
from rdsl.runtime.render.kernel_source import literal

# (kind, param, param2): box, tent, gaussian, mitchell (B, C), lanczos (lobes)
FILTERS = [(0, 0.5, 0.0), (1, 1.0, 0.0), (1, 1.6, 0.0), (2, 0.5, 0.0), (3, 1 / 3, 1 / 3),
           (4, 3.0, 0.0)]


def film_for(kind: int, param: float, spp: int, param2: float = 0.0) -> dict:
    return {"crop_x": 2, "crop_y": 1, "crop_w": 12, "crop_h": 9, "grid_x": 0, "grid_y": 0,
            "grid_w": 16, "grid_h": 12, "spp": spp, "channels": 3, "filter": kind,
            "filter_param": param, "filter_param2": param2}


def source(film: dict) -> str:
    lit = literal(dict(film, spp=0), "Film")
    m = 2 * film_reach(film) + 1
    fields = ", ".join(f"w{k}: Float" for k in range(2 * m))
    ws = ", ".join([f"w{k}: film_axis_weight(film, x, gx - n + {k})" for k in range(m)]
                   + [f"w{m + k}: film_axis_weight(film, y, gy - n + {k})" for k in range(m)])
    return f"""
import render.film;
struct W {{ {fields} }}
fn weights(x: Float, y: Float, gx: Int, gy: Int, spp: Int) -> W {{
    var film = {lit}; film.spp = spp;
    let n = film_reach(film);
    return W {{ {ws} }};
}}
fn direct(pixel: Int, spp: Int, pos: [Float], values: [Float], acc: [Float]) -> Int {{
    var film = {lit}; film.spp = spp; return film_accumulate(pixel, film, pos, values, acc);
}}
fn separable(pixel: Int, spp: Int, S: [Float], ns: Int, acc: [Float]) {{
    var film = {lit}; film.spp = spp; film_accumulate_separable(pixel, film, S, ns, acc);
}}
"""


@pytest.mark.parametrize("kind,param,param2", FILTERS)
def test_separable_equals_direct(kind, param, param2):
    spp = 3
    film = film_for(kind, param, spp, param2)
    mod = rdsl.jit(source(film), target="host")
    cells = film["grid_w"] * film["grid_h"]
    rng = np.random.default_rng(kind * 10 + int(param * 10))
    cell = np.tile(np.arange(cells, dtype=np.int32), spp)  # sample-major
    gx, gy = cell % film["grid_w"], cell // film["grid_w"]
    x = (gx + rng.random(cell.size)).astype(np.float32)
    y = (gy + rng.random(cell.size)).astype(np.float32)
    vals = rng.random((cell.size, 3)).astype(np.float32).reshape(-1)
    w = mod.weights(x, y, gx.astype(np.int32), gy.astype(np.int32), spp)
    # structure of arrays: the 3 channels, then the weights, one row per quantity
    S = np.ascontiguousarray(np.concatenate([vals.reshape(-1, 3).T,
                                             np.stack([w[f"w{k}"] for k in range(len(w))])]))
    pixels = np.arange(film["crop_w"] * film["crop_h"], dtype=np.int32)
    a = new_accumulator(film)
    # film_accumulate reads cell-major samples: cell by cell, a cell's samples together
    cm = np.arange(cell.size).reshape(spp, cells).T.reshape(-1)
    mod.direct(pixels, spp, np.ascontiguousarray(np.stack([x, y], 1)[cm].reshape(-1)),
               np.ascontiguousarray(vals.reshape(-1, 3)[cm].reshape(-1)), a)
    b = new_accumulator(film)
    mod.separable(pixels, spp, S.reshape(-1), cell.size, b)
    np.testing.assert_allclose(b, a, rtol=2e-6, atol=1e-7)
    assert np.all(a[3::4] > 0)  # every pixel got weight
