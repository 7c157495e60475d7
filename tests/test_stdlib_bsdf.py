"""The stdlib BSDF plugins (`diffuse`, `roughconductor`) against the `bsdf` interface.

For each: sample() is consistent with eval() and pdf() (weight = eval / pdf, the sampled pdf
equals pdf()), samples follow pdf() (chi-square), pdf() integrates to the fraction of valid
samples, and nothing returns NaN or Inf at grazing angles or extreme roughness.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rdsl
from test_stdlib_sampling import chi2_test, integrate_sphere, sph

STDLIB = Path(__file__).resolve().parents[1] / "stdlib"
DIFFUSE = str(STDLIB / "bsdf" / "diffuse.rdsl")
ROUGHCONDUCTOR = str(STDLIB / "bsdf" / "roughconductor.rdsl")
f32 = np.float32
RNG = np.random.default_rng(99)
GOLD = {"eta": (0.143, 0.374, 1.442), "k": (3.983, 2.385, 1.603)}  # Au, roughly, in RGB


@pytest.fixture(scope="module")
def diffuse():
    return rdsl.jit(DIFFUSE, target="scalar")


@pytest.fixture(scope="module")
def rough():
    return rdsl.jit(ROUGHCONDUCTOR, target="scalar")


def surface(wi: np.ndarray) -> dict:
    """A Surface record per row of wi (local frame; the other fields are placeholders)."""
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def tile(v: np.ndarray, n: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(v, f32), (n, 3)))


def wi_at(theta: float, phi: float = 0.4) -> np.ndarray:
    return sph(np.array([theta]), np.array([phi]))[0]


def run_sample(mod, name, wi, n, **params):
    si = surface(tile(wi, n))
    bs = mod[f"{name}.sample"](si, RNG.random(n).astype(f32), RNG.random((n, 2)).astype(f32),
                               **params)
    return si, bs


def check_consistency(mod, name, wi, n=20_000, **params):
    si, bs = run_sample(mod, name, wi, n, **params)
    wo, pdf, weight = bs["wo"], bs["pdf"], np.asarray(bs["weight"]).reshape(n, -1)
    for a in (wo, pdf, weight):
        assert np.all(np.isfinite(a))
    assert np.all(pdf >= 0) and np.all(weight >= 0)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1, atol=1e-5)
    ok = pdf > 0
    ev = np.asarray(mod[f"{name}.eval"](si, wo, **params)).reshape(n, -1)
    pd = mod[f"{name}.pdf"](si, wo, **params)
    assert np.all(np.isfinite(ev)) and np.all(np.isfinite(pd))
    np.testing.assert_allclose(pd[ok], pdf[ok], rtol=2e-3)
    np.testing.assert_allclose(ev[ok] / pd[ok, None], weight[ok], rtol=2e-3, atol=1e-6)
    assert np.all(weight[~ok] == 0)
    return si, bs


# ---------------------------------------------------------------------------- diffuse

@pytest.mark.parametrize("theta_i", [0.0, 0.8, 1.5])
def test_diffuse_consistent(diffuse, theta_i):
    _, bs = check_consistency(diffuse, "diffuse", wi_at(theta_i), reflectance=0.7)
    np.testing.assert_allclose(np.asarray(bs["weight"])[bs["pdf"] > 0], 0.7, rtol=1e-6)
    assert np.all(bs["eta"] == 1)


def test_diffuse_distribution(diffuse):
    wi = wi_at(0.5)
    _, bs = run_sample(diffuse, "diffuse", wi, 100_000)
    pdf = diffuse["diffuse.pdf"]

    def p(d):
        return pdf(surface(tile(wi, len(d))), d)

    chi2_test(bs["wo"], p, np.linspace(0, np.pi / 2, 13))
    assert integrate_sphere(p, np.pi / 2) == pytest.approx(1.0, abs=2e-4)


def test_diffuse_below_horizon(diffuse):
    n = 1000
    wi = tile(wi_at(2.0), n)
    wo = sph(RNG.uniform(0, np.pi, n), RNG.uniform(0, 2 * np.pi, n))
    si = surface(wi)
    assert np.all(np.asarray(diffuse["diffuse.eval"](si, wo)) == 0)
    assert np.all(diffuse["diffuse.pdf"](si, wo) == 0)
    bs = diffuse["diffuse.sample"](si, RNG.random(n).astype(f32), RNG.random((n, 2)).astype(f32))
    assert np.all(bs["pdf"] == 0) and np.all(np.asarray(bs["weight"]) == 0)


# ---------------------------------------------------------------------------- roughconductor

@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
@pytest.mark.parametrize("theta_i", [0.0, 0.7, 1.3, 1.55])
def test_roughconductor_consistent(rough, alpha, theta_i):
    check_consistency(rough, "roughconductor", wi_at(theta_i), alpha=alpha, **GOLD)


@pytest.mark.parametrize("alpha", [0.2, 0.5, 1.0])
@pytest.mark.parametrize("theta_i", [0.0, 0.7, 1.3])
def test_roughconductor_distribution(rough, alpha, theta_i):
    n = 100_000
    wi = wi_at(theta_i)
    _, bs = run_sample(rough, "roughconductor", wi, n, alpha=alpha)
    valid = bs["pdf"] > 0
    pdf = rough["roughconductor.pdf"]

    def p(d):
        return pdf(surface(tile(wi, len(d))), d, alpha=alpha)

    chi2_test(bs["wo"][valid], lambda d: p(d) / valid.mean(), np.linspace(0, np.pi / 2, 25),
              n_phi=24, sub=12)
    # pdf() integrates to the probability that a sample is valid (above the horizon)
    total = integrate_sphere(p, theta_edges=np.linspace(0, np.pi / 2, 513), n_phi=256)
    sigma = np.sqrt(valid.mean() * (1 - valid.mean()) / n)
    assert abs(total - valid.mean()) < 5 * sigma + 2e-3


def test_roughconductor_mirror_energy(rough):
    """Mitsuba's defaults (eta = 0, k = 1) are a perfect mirror: the albedo is the fraction of
    light that is not masked, at most 1, and 1 at low roughness and normal incidence."""
    n = 50_000
    for alpha, theta_i, lo in [(1e-3, 0.0, 0.999), (0.1, 0.5, 0.98), (1.0, 1.2, 0.3)]:
        _, bs = run_sample(rough, "roughconductor", wi_at(theta_i), n, alpha=alpha)
        albedo = np.asarray(bs["weight"]).reshape(n, -1).mean(0)
        assert np.all(albedo <= 1.0 + 1e-4) and np.all(albedo >= lo), (alpha, theta_i, albedo)


def test_roughconductor_robust(rough):
    """No NaN or Inf for grazing directions, roughness near 0 and 1, and IOR near 1."""
    n = 4096
    wo = np.concatenate([sph(RNG.uniform(0, np.pi, n - 4), RNG.uniform(0, 2 * np.pi, n - 4)),
                         [[0, 0, 1], [1, 0, 0], [0, 1, 1e-7], [0, 0, -1]]]).astype(f32)
    for alpha in (0.0, 1e-4, 1e-2, 1.0):
        for theta_i in (0.0, 1e-4, 1.5, 1.5707, np.pi / 2):
            for params in (GOLD, {"eta": 1.0001, "k": 0.0}, {"eta": 1.0, "k": 0.0}, {}):
                wi = tile(wi_at(theta_i), n)
                si = surface(wi)
                ev = np.asarray(rough["roughconductor.eval"](si, wo, alpha=alpha, **params))
                pd = rough["roughconductor.pdf"](si, wo, alpha=alpha, **params)
                where = (alpha, theta_i, params)
                assert np.all(np.isfinite(ev) & (ev >= 0)), where
                assert np.all(np.isfinite(pd) & (pd >= 0)), where
                bs = rough["roughconductor.sample"](si, RNG.random(n).astype(f32),
                                                    RNG.random((n, 2)).astype(f32),
                                                    alpha=alpha, **params)
                for k in ("wo", "pdf", "weight"):
                    assert np.all(np.isfinite(np.asarray(bs[k]))), (k, where)
                assert np.all(np.asarray(bs["weight"]) >= 0), where


def test_roughconductor_texture_scales(rough):
    n = 2000
    si, bs = run_sample(rough, "roughconductor", wi_at(0.6), n, alpha=0.3)
    ev1 = np.asarray(rough["roughconductor.eval"](si, bs["wo"], alpha=0.3))
    ev2 = np.asarray(rough["roughconductor.eval"](si, bs["wo"], alpha=0.3,
                                                  specular_reflectance=0.25))
    np.testing.assert_allclose(ev2, 0.25 * ev1, rtol=1e-6)


def test_roughconductor_host_matches_scalar(rough):
    host = rdsl.jit(ROUGHCONDUCTOR, target="host")
    n = 4096
    wi = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 2 * np.pi, n))
    wo = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 2 * np.pi, n))
    si = surface(wi)
    u1, u2 = RNG.random(n).astype(f32), RNG.random((n, 2)).astype(f32)
    for fn, args in [("eval", (si, wo)), ("pdf", (si, wo)), ("sample", (si, u1, u2))]:
        a = host[f"roughconductor.{fn}"](*args, alpha=0.4, **GOLD)
        b = rough[f"roughconductor.{fn}"](*args, alpha=0.4, **GOLD)
        if isinstance(a, dict):
            for k in a:
                np.testing.assert_allclose(a[k], b[k], rtol=1e-6, atol=1e-7, err_msg=k)
        else:
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7, err_msg=fn)
