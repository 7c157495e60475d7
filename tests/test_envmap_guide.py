"""The environment map's CDF search with its guide table (stdlib/emitter/envmap.rdsl's
envmap_cdf_find, runtime/render/emitters.py's cdf_guide) finds the cell an exhaustive search
finds: the first i with C[i + 1] > u (n - 1 if none), for u on and beside every slice
boundary g / G and at random, over CDFs with zero-probability cells and a single cell."""

import numpy as np
import pytest

import rdsl
from rdsl.runtime.render.emitters import cdf_guide

SRC = """
import emitter.envmap;
fn find(u: Float, n: Int, C: [Float]) -> Int { return envmap_cdf_find(C, 0, n, n + 1, u); }
"""


@pytest.fixture(scope="module")
def mod():
    return rdsl.jit(SRC)


def cdfs():
    rng = np.random.default_rng(5)
    out = []
    for n in (1, 2, 5, 16, 17, 100):
        p = rng.uniform(0, 1, n) ** 4
        p[rng.uniform(0, 1, n) < 0.3] = 0.0  # cells never chosen
        if not p.any():
            p[0] = 1.0
        c = np.concatenate([[0.0], np.cumsum(p) / p.sum()])
        c[-1] = 1.0
        out.append(c.astype(np.float32))
    return out


@pytest.mark.parametrize("cdf", cdfs(), ids=lambda c: f"n{len(c) - 1}")
def test_guided_search_finds_the_first_cell(mod, cdf):
    n = len(cdf) - 1
    guide = cdf_guide(cdf)
    g = len(guide) - 1
    edges = (np.arange(g) / g).astype(np.float32)
    u = np.concatenate([edges, np.nextafter(edges, np.float32(1)),
                        np.nextafter(edges[1:], np.float32(0)), cdf[:-1],
                        np.nextafter(cdf[1:-1], np.float32(0)),
                        np.float32([np.nextafter(np.float32(1), np.float32(0))]),
                        np.random.default_rng(1).random(2000).astype(np.float32)])
    u = u[(u >= 0) & (u < 1)].astype(np.float32)
    want = np.minimum(np.searchsorted(cdf[1:], u, side="right"), n - 1)
    got = np.asarray(mod["find"](u, n, np.concatenate([cdf, guide])))
    np.testing.assert_array_equal(got, want)
