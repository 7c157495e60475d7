"""Anisotropic roughdielectric (alpha_u != alpha_v) against Mitsuba 3 itself (skipped without
the `mitsuba` package): eval() and pdf() of stdlib/bsdf/roughdielectric.rdsl in the `rgb`
variant against Mitsuba's `roughdielectric` in `scalar_rgb`, for random pairs of directions
(reflection and transmission, light from outside and inside), GGX and Beckmann, with
alpha_u = 0.1 along the shading frame's x axis and alpha_v = 0.4 along y.  (sample()
against pdf() by chi-square: tests/test_bsdf_plugins.py; the scene's `alpha_u`/`alpha_v`:
tests/test_scene_bsdfs.py and tests/test_textured_params.py.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rdsl
from _mitsuba_render import mitsuba_variant

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
f32 = np.float32
AU, AV = 0.1, 0.4


@pytest.fixture(scope="module")
def mi():
    with mitsuba_variant("scalar_rgb") as mitsuba:
        yield mitsuba


@pytest.fixture(scope="module")
def mod():
    return rdsl.jit(str(STDLIB / "bsdf" / "roughdielectric.rdsl"), target="host", variant="rgb")


def _surfaces(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def _random_dirs(gen: np.random.Generator, n: int) -> np.ndarray:
    d = gen.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d.astype(f32)


def _mi_si(mi, wi):
    si = mi.SurfaceInteraction3f()
    si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
    si.wi = [float(x) for x in wi]
    return si


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_eval_pdf_match_mitsuba(mi, mod, dist):
    bsdf = mi.load_dict({"type": "roughdielectric", "distribution": dist, "alpha_u": AU,
                         "alpha_v": AV, "int_ior": 1.5, "ext_ior": 1.0})
    ctx = mi.BSDFContext()
    gen = np.random.default_rng(12 + len(dist))
    n = 2000
    wi, wo = _random_dirs(gen, n), _random_dirs(gen, n)
    # the anisotropy shows most where wo is near the mirror or refracted direction: half of
    # the pairs get wo from the plugin's own sampler
    params = {"distribution": 0 if dist == "ggx" else 1, "alpha": AU, "alpha_v": AV,
              "int_ior": 1.5, "ext_ior": 1.0}
    bs = mod["roughdielectric.sample"](_surfaces(wi[: n // 2]), gen.random(n // 2).astype(f32),
                                       gen.random((n // 2, 2)).astype(f32), **params)
    ok = np.asarray(bs["pdf"]) > 0
    wo[: n // 2][ok] = np.asarray(bs["wo"])[ok]
    si = _surfaces(wi)
    ours = np.asarray(mod["roughdielectric.eval"](si, wo, **params)).reshape(n, 3)
    ours_pdf = np.asarray(mod["roughdielectric.pdf"](si, wo, **params))
    theirs = np.array([np.array(bsdf.eval(ctx, _mi_si(mi, wi[i]), [float(x) for x in wo[i]]))
                       for i in range(n)])
    theirs_pdf = np.array([float(bsdf.pdf(ctx, _mi_si(mi, wi[i]), [float(x) for x in wo[i]]))
                           for i in range(n)])
    nonzero = theirs[:, 0] > 0
    assert nonzero.sum() > n // 3  # reflection and transmission pairs were compared
    assert np.sum((wi[:, 2] * wo[:, 2] < 0) & nonzero) > n // 10
    # float32 on both sides; relative to the value, with an absolute floor for the tails
    np.testing.assert_allclose(ours, theirs, rtol=2e-3, atol=1e-5 * theirs.max())
    np.testing.assert_allclose(ours_pdf, theirs_pdf, rtol=2e-3, atol=1e-5 * theirs_pdf.max())
    # the same pairs with alpha_u and alpha_v swapped differ: the test sees the orientation
    swapped = {**params, "alpha": AV, "alpha_v": AU}
    other = np.asarray(mod["roughdielectric.eval"](si, wo, **swapped)).reshape(n, 3)
    assert np.abs(other - theirs).max() > 0.1 * theirs.max()

