"""Every stdlib BSDF plugin against the `bsdf` interface, Mitsuba 3 style.

For each plugin (diffuse, roughconductor, conductor, dielectric, thindielectric,
roughdielectric, plastic, roughplastic, blend_example):

1. sampling: Pearson's chi-square of sample() against pdf() over bins in (cos theta, phi),
   with the expected counts integrated from pdf() by adaptive Gauss-Legendre quadrature, the
   sparse bins (expected < 5) pooled, plus one cell for the invalid samples (pdf 0) and one
   per Dirac lobe; p-value threshold 1e-3 with a fixed seed (Mitsuba's ChiSquareTest). Delta
   BSDFs: the discrete lobe probabilities instead (binomial, 5 sigma) and exact directions;
2. sample() agrees with eval() and pdf(): weight == eval / pdf, pdf == pdf() (rtol 1e-4);
3. white furnace: the albedo (mean sample weight) is <= 1 + 3 sigma, and ~1 for the
   lossless ones (tolerances stated per test);
4. no NaN / Inf (and nothing negative) at grazing angles, alpha 1e-4 and 1, IOR 1.0001 and 1.

Every test runs in the five variants (mono, rgb, spectral, mono_polarized,
spectral_polarized): each plugin is called as the renderer calls it, through the scene
dispatch of a kernel that first sets the sample's wavelengths (rdsl.runtime.testkit.harness).
Values compared are the intensity ([0][0] of the Mueller matrix in polarized variants); the
whole Mueller matrix must be finite, and equal eval / pdf for a sample. A colour is a
variant's own: its luminance in mono, and in spectral variants the Jakob & Hanika upsampling
(or a tabulated spectrum: gold's eta and k) at the wavelengths of each row. rgb runs the full
grids; the other variants a reduced grid of the same cases (the sampled directions do not
depend on the variant; what does -- the lifted colour arithmetic -- is in every case).

Each plugin compiles once per variant (target "host"; the generic build, whose parameters are
read at run time).
"""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _bsdf_harness import VARIANTS, Harness, colour_at, ior_table
from rdsl.core.scene_spec import SpectrumValue
from rdsl.runtime.testkit.chi2 import beckmann_g1_exact, beckmann_g1_fit, chi2_directions

BSDF_DIR = Path(__file__).resolve().parents[1] / "stdlib" / "bsdf"
PLUGINS = ["diffuse", "roughconductor", "conductor", "dielectric", "thindielectric",
           "roughdielectric", "plastic", "roughplastic", "blend_example"]
f32 = np.float32
P_MIN = 1e-3
GOLD = {"eta": (0.143, 0.374, 1.442), "k": (3.983, 2.385, 1.603)}  # Au, roughly, in RGB
OTHERS = [v for v in VARIANTS if v != "rgb"]  # the variants that run the reduced grids
THETAS = [0.3, 1.0, 1.45]          # incident angles; 1.45 rad = 83 degrees: near grazing
ALPHAS = [0.05, 0.3, 0.7]


@pytest.fixture(scope="module")
def mods():
    """mods(name, variant): the plugin through the scene dispatch (a module look-alike)."""
    cache: dict[tuple[str, str], Harness] = {}

    def get(name: str, variant: str = "rgb") -> Harness:
        if (name, variant) not in cache:
            cache[name, variant] = Harness(name, variant)
        return cache[name, variant]
    return get


def gold(variant: str) -> dict:
    """Gold's complex IOR as a scene gives it: RGB in mono and rgb, the tabulated spectra
    (stdlib/data/ior/Au.*.spd, as `material="Au"`) in the spectral variants."""
    if variant.removesuffix("_polarized") != "spectral":
        return GOLD
    return {k: SpectrumValue(GOLD[k], ior_table(f"Au.{k}.spd")) for k in ("eta", "k")}


def in_variant(params: dict, variant: str) -> dict:
    """`params` with GOLD as `variant` takes it."""
    if params.get("eta") == GOLD["eta"]:
        return {**params, **gold(variant)}
    return params


def rng(*key) -> np.random.Generator:
    """A fixed seed per test case."""
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


# ---------------------------------------------------------------------------- helpers

def sph(theta, phi) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta) + 0 * phi],
                    -1).astype(f32)


def wi_at(theta: float, phi: float = 0.4) -> np.ndarray:
    return sph(np.float64(theta), np.float64(phi))


def surface(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def tile(v, n: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(v, f32), (n, 3)))


def sample(mod, name, wi, n, gen, **params):
    si = surface(tile(wi, n))
    bs = mod[f"{name}.sample"](si, gen.random(n).astype(f32), gen.random((n, 2)).astype(f32),
                               **params)
    bs = {k: np.asarray(v) for k, v in bs.items()}
    bs["weight"] = bs["weight"].reshape(n, -1)
    return si, bs


def pdf_fn(mod, name, wi, **params):
    k = mod[f"{name}.pdf"]
    return lambda d: np.asarray(k(surface(tile(wi, len(d))), np.ascontiguousarray(d, f32),
                                  **params), np.float64)


def fresnel_np(cos_i, eta):
    """Unpolarized dielectric Fresnel reflectance (independent of the rdsl one)."""
    cos_i = np.asarray(cos_i, np.float64)
    eta = np.where(cos_i >= 0, eta, 1 / eta)
    c = np.abs(cos_i)
    s2t = (1 - c * c) / eta ** 2
    ct = np.sqrt(np.maximum(1 - s2t, 0))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return np.where(s2t >= 1, 1.0, 0.5 * (rs * rs + rp * rp))


CHI2_CASES = (
    [("diffuse", {"reflectance": 0.7}, t) for t in THETAS]
    + [("roughconductor", {"alpha": a, **GOLD}, t) for a in ALPHAS for t in THETAS]
    + [("roughconductor", {"alpha": a, "distribution": 1, **GOLD}, t) for a in (0.05, 0.7)
       for t in (0.3, 1.45)]
    + [("roughconductor", {"alpha": 0.1, "alpha_v": 0.5, "distribution": d, **GOLD}, t)
       for d in (0, 1) for t in THETAS]
    + [("roughdielectric", {"alpha": a, "distribution": d}, t)
       for d in (0, 1) for a in ALPHAS for t in THETAS]
    + [("roughdielectric", {"alpha": a}, np.pi - t) for a in (0.05, 0.3) for t in (0.3, 1.0)]
    + [("roughdielectric", {"alpha": 0.1, "alpha_v": 0.4, "distribution": d}, t)
       for d in (0, 1) for t in (0.3, 1.0)]
    + [("roughdielectric", {"alpha": 0.1, "alpha_v": 0.4, "distribution": 0}, np.pi - 1.0)]
    + [("roughplastic", {"alpha": a, "diffuse_reflectance": 0.6}, t)
       for a in ALPHAS for t in THETAS]
    + [("roughplastic", {"alpha": 0.3, "distribution": 1}, 1.0)]
    + [("blend_example", {"alpha": a, "weight": 0.4, **GOLD}, t) for a in ALPHAS
       for t in THETAS]
)


def _case_id(c):
    name, params, theta = c
    extra = ",".join(f"{k}={v}" for k, v in params.items()
                     if k in ("alpha", "alpha_v", "distribution"))
    return f"{name}[{extra}]@{theta:.2f}"


# the reduced grid of the other variants: each plugin, each distribution, anisotropy, inside
CHI2_REDUCED = ["diffuse[]@1.00", "roughconductor[alpha=0.3]@1.00",
                "roughconductor[alpha=0.7,distribution=1]@1.45",
                "roughconductor[alpha=0.1,alpha_v=0.5,distribution=0]@1.00",
                "roughdielectric[alpha=0.3,distribution=0]@1.00",
                "roughdielectric[alpha=0.05,distribution=1]@0.30",
                f"roughdielectric[alpha=0.3]@{np.pi - 1.0:.2f}",
                "roughdielectric[alpha=0.1,alpha_v=0.4,distribution=1]@1.00",
                "roughplastic[alpha=0.3]@1.00", "blend_example[alpha=0.3]@1.45"]
_CHI2_BY_ID = {_case_id(c): c for c in CHI2_CASES}
assert set(CHI2_REDUCED) <= set(_CHI2_BY_ID)
CHI2_GRID = ([("rgb", c) for c in CHI2_CASES]
             + [(v, _CHI2_BY_ID[i]) for v in OTHERS for i in CHI2_REDUCED])


@pytest.mark.parametrize("variant,case", CHI2_GRID,
                         ids=[f"{v}-{_case_id(c)}" for v, c in CHI2_GRID])
def test_chi2(mods, variant, case):
    name, params, theta = case
    mod = mods(name, variant)
    params = in_variant(params, variant)
    n = 200_000 if name == "roughplastic" else 500_000
    wi = wi_at(theta)
    _, bs = sample(mod, name, wi, n, rng(name, theta, *params.values()), **params)
    valid = bs["pdf"] > 0
    lower = name in ("roughdielectric",)
    pdf = pdf_fn(mod, name, wi, **params)
    if name in ("roughdielectric", "roughconductor") and params.get("distribution") == 1:
        # pdf() uses the rational fit of Beckmann's G1(wi) (as Mitsuba), sample() the exact
        # visible-normal distribution: a constant factor (<= 0.35%) for a fixed wi, that
        # matters with 1e5 samples (the invalid-sample cell is 1 - the integral of pdf).
        # (anisotropic: the roughness projected on wi's azimuth)
        ax, ay = params["alpha"], params.get("alpha_v", params["alpha"])
        phi = np.arctan2(wi[1], wi[0])
        a = float(np.hypot(ax * np.cos(phi), ay * np.sin(phi)))
        scale = beckmann_g1_exact(wi, a) / beckmann_g1_fit(wi, a)
        pdf = (lambda f, c: (lambda d: c * f(d)))(pdf, scale)
    p = chi2_directions(bs["wo"], valid, pdf, n, lower=lower,
                        res=(60, 40) if lower else (40, 40))
    assert p > P_MIN, f"{_case_id(case)}: p = {p:.2e}"


@pytest.mark.parametrize("variant", VARIANTS)
def test_chi2_plastic(mods, variant):
    """The smooth plastic: a Dirac lobe (the mirror direction) plus a diffuse lobe."""
    mod, eta = mods("plastic", variant), 1.49 / 1.000277
    for theta in THETAS if variant == "rgb" else [1.0]:
        wi = wi_at(theta)
        n = 500_000
        params = {"diffuse_reflectance": 0.6}
        _, bs = sample(mod, "plastic", wi, n, rng("plastic", theta), **params)
        mirror = np.all(bs["wo"] == np.array([-wi[0], -wi[1], wi[2]], f32), axis=1)
        f = fresnel_np(np.cos(theta), eta)
        w = 1.0 / (0.6 + 1.0)
        p_spec = f * w / (f * w + (1 - f) * (1 - w))
        np.testing.assert_allclose(bs["pdf"][mirror], p_spec, rtol=1e-4)
        p = chi2_directions(bs["wo"], (bs["pdf"] > 0) & ~mirror,
                            pdf_fn(mod, "plastic", wi, **params), n,
                            delta_obs=[mirror.sum()], delta_prob=[p_spec], lower=False)
        assert p > P_MIN, (theta, p)


@pytest.mark.parametrize("variant", VARIANTS)
def test_colour_in_every_variant(mods, variant):
    """A colour is the variant's own: diffuse's sample weight is the reflectance in RGB, its
    luminance in mono, the Jakob & Hanika spectrum at each row's wavelengths (numpy's model,
    rdsl.core.spectral) in spectral variants; the intensity entry in polarized ones."""
    mod, n, rgb = mods("diffuse", variant), 2000, (0.8, 0.5, 0.2)
    _, bs = sample(mod, "diffuse", wi_at(0.7), n, rng("colour", variant), reflectance=rgb)
    want = colour_at(variant, rgb, mod.wavelengths(n))
    np.testing.assert_allclose(bs["weight"], np.broadcast_to(want, bs["weight"].shape),
                               rtol=2e-5, atol=1e-6)
    if "mueller" in bs:
        assert np.all(np.isfinite(bs["mueller"]))


# ---------------------------------------------------------------------------- delta lobes

@pytest.mark.parametrize("variant", VARIANTS)
def test_conductor_delta(mods, variant):
    """The mirror direction with pdf 1 and the weight F of the complex IOR: per RGB channel,
    of the luminances of eta and k (mono), at each row's wavelengths (spectral: gold's
    tables)."""
    mod, params, n = mods("conductor", variant), gold(variant), 1000
    lam = mod.wavelengths(n)
    eta, k = (colour_at(variant, params[x], lam) for x in ("eta", "k"))
    for theta in [0.0, 0.7, 1.3, 1.5707]:
        wi = wi_at(theta)
        si, bs = sample(mod, "conductor", wi, n, rng("cond", theta), **params)
        np.testing.assert_array_equal(bs["wo"], tile([-wi[0], -wi[1], wi[2]], n))
        assert np.all(bs["pdf"] == 1)
        # against the Fresnel equations for a complex IOR (numpy, complex arithmetic)
        n_c = eta + 1j * k
        c = np.cos(theta)
        ct = np.sqrt(1 - (1 - c * c) / n_c ** 2)
        rs = np.abs((c - n_c * ct) / (c + n_c * ct)) ** 2
        rp = np.abs((n_c * c - ct) / (n_c * c + ct)) ** 2
        ref = np.broadcast_to(0.5 * (rs + rp), bs["weight"].shape)
        np.testing.assert_allclose(bs["weight"], ref, rtol=2e-4)
        assert np.all(np.asarray(mod["conductor.eval"](si, bs["wo"], **params)) == 0)
        assert np.all(mod["conductor.pdf"](si, bs["wo"], **params) == 0)
    _, bs = sample(mod, "conductor", wi_at(2.0), 100, rng("cond-below"))
    assert np.all(bs["pdf"] == 0) and np.all(bs["weight"] == 0)


DIELECTRIC_THETAS = [0.0, 0.5, 1.0, 1.4, np.pi - 0.3, np.pi - 0.8, np.pi - 1.2]
DIELECTRIC_GRID = ([("rgb", t) for t in DIELECTRIC_THETAS]
                   + [(v, t) for v in OTHERS for t in (1.0, np.pi - 0.3)])


@pytest.mark.parametrize("variant,theta", DIELECTRIC_GRID)
def test_dielectric_delta(mods, variant, theta):
    """Reflection with probability F, refraction by Snell's law otherwise (both sides, total
    internal reflection included); eta^2 radiance scaling and BsdfSample.eta."""
    mod, n = mods("dielectric", variant), 200_000
    eta = 1.5046 / 1.000277
    wi = wi_at(theta)
    si, bs = sample(mod, "dielectric", wi, n, rng("diel", theta))
    refl = bs["wo"][:, 2] * wi[2] > 0
    f = float(fresnel_np(wi[2], eta))
    assert abs(refl.mean() - f) <= 5 * np.sqrt(f * (1 - f) / n) + 1e-12, (refl.mean(), f)
    np.testing.assert_allclose(bs["wo"][refl], tile([-wi[0], -wi[1], wi[2]], refl.sum()),
                               atol=1e-6)
    np.testing.assert_allclose(bs["pdf"][refl], f, rtol=1e-5)
    # (polarized: the Mueller matrix over F, whose intensity is 1 up to rounding)
    assert np.all(bs["eta"][refl] == 1)
    np.testing.assert_allclose(bs["weight"][refl], 1, rtol=1e-6 if mod.polarized else 0)
    if f < 1:
        t = bs["wo"][~refl]
        eta_it = eta if wi[2] > 0 else 1 / eta
        # Snell: sin theta_t = sin theta_i / eta_it, in the plane of incidence, other side
        np.testing.assert_allclose(np.linalg.norm(t[:, :2], axis=1),
                                   np.linalg.norm(wi[:2]) / eta_it, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(t[:, :2], np.broadcast_to(-wi[:2] / eta_it, t[:, :2].shape),
                                   atol=1e-6)
        assert np.all(t[:, 2] * wi[2] < 0)
        np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1, atol=1e-6)
        np.testing.assert_allclose(bs["pdf"][~refl], 1 - f, rtol=1e-4)
        np.testing.assert_allclose(bs["eta"][~refl], eta_it, rtol=1e-6)
        np.testing.assert_allclose(bs["weight"][~refl], 1 / eta_it ** 2, rtol=1e-5)
    # white furnace: every sample carries the flux weight (weight * eta^2) 1; the radiance
    # albedo is F + (1 - F) / eta_it^2
    np.testing.assert_allclose(bs["weight"][:, 0] * bs["eta"] ** 2, 1, rtol=1e-5)
    assert np.all(np.asarray(mod["dielectric.eval"](si, bs["wo"])) == 0)
    assert np.all(mod["dielectric.pdf"](si, bs["wo"]) == 0)


THIN_GRID = ([("rgb", t) for t in (0.0, 0.8, 1.4, np.pi - 0.8)]
             + [(v, t) for v in OTHERS for t in (0.8, np.pi - 0.8)])


@pytest.mark.parametrize("variant,theta", THIN_GRID)
def test_thindielectric_delta(mods, variant, theta):
    mod, n = mods("thindielectric", variant), 200_000
    eta = 1.5046 / 1.000277
    wi = wi_at(theta)
    _, bs = sample(mod, "thindielectric", wi, n, rng("thin", theta))
    refl = bs["wo"][:, 2] * wi[2] > 0
    r = float(fresnel_np(abs(wi[2]), eta))
    r = 2 * r / (1 + r)
    assert abs(refl.mean() - r) <= 5 * np.sqrt(r * (1 - r) / n), (refl.mean(), r)
    np.testing.assert_array_equal(bs["wo"][~refl], tile(-wi, (~refl).sum()))
    np.testing.assert_allclose(bs["wo"][refl], tile([-wi[0], -wi[1], wi[2]], refl.sum()))
    np.testing.assert_allclose(bs["pdf"], np.where(refl, r, 1 - r), rtol=1e-5)
    # lossless: every weight is 1
    assert np.all(bs["weight"] == 1) and np.all(bs["eta"] == 1)


# ---------------------------------------------------------------------------- consistency

CONSISTENCY = (
    [("diffuse", {"reflectance": (0.8, 0.5, 0.2)})]
    + [("roughconductor", {"alpha": a, **GOLD}) for a in ALPHAS]
    + [("roughconductor", {"alpha": 0.05, "alpha_v": 0.6, "distribution": d, **GOLD})
       for d in (0, 1)]
    + [("roughdielectric", {"alpha": a, "distribution": d}) for a in ALPHAS for d in (0, 1)]
    + [("roughdielectric", {"alpha": 0.1, "alpha_v": 0.4, "distribution": d}) for d in (0, 1)]
    + [("roughplastic", {"alpha": a, "distribution": d}) for a in (0.05, 0.7) for d in (0, 1)]
    + [("plastic", {})]
    + [("blend_example", {"alpha": a, **GOLD}) for a in ALPHAS]
)


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name,params", CONSISTENCY,
                         ids=[f"{c[0]}-{c[1].get('alpha', '')}-{c[1].get('distribution', 0)}"
                              for c in CONSISTENCY])
def test_sample_matches_eval_pdf(mods, variant, name, params):
    """In polarized variants the whole Mueller matrix of the weight is eval / pdf."""
    mod, n = mods(name, variant), 4000
    params = in_variant(params, variant)
    thetas = [0.0, 0.5, 1.2, 1.5] + ([np.pi - 0.5, np.pi - 1.2] if name == "roughdielectric"
                                     else [])
    for theta in thetas:
        wi = wi_at(theta)
        si, bs = sample(mod, name, wi, n, rng("cons", name, theta), **params)
        wo, pdf, weight = bs["wo"], bs["pdf"], bs["weight"]
        assert np.all(np.isfinite(wo)) and np.all(np.isfinite(pdf)) and np.all(np.isfinite(weight))
        assert np.all(pdf >= 0) and np.all(weight >= 0)
        ok = pdf > 0
        if name == "plastic":   # the Dirac lobe is not in eval() / pdf()
            ok &= ~np.all(wo == np.array([-wi[0], -wi[1], wi[2]], f32), axis=1)
        assert np.all(weight[~(pdf > 0)] == 0)
        np.testing.assert_allclose(np.linalg.norm(wo[ok], axis=1), 1, atol=1e-5)
        ev = np.asarray(mod[f"{name}.eval"](si, wo, **params)).reshape(n, -1)
        pd = np.asarray(mod[f"{name}.pdf"](si, wo, **params))
        # (pdf() recomputes the half vector from wo: float32 rounding, mostly for refraction)
        np.testing.assert_allclose(pd[ok], pdf[ok], rtol=1e-3, err_msg=f"pdf, theta {theta}")
        np.testing.assert_allclose(ev[ok] / pd[ok, None], weight[ok], rtol=1e-4, atol=1e-7,
                                   err_msg=f"weight, theta {theta}")
        if "mueller" in bs:
            m, em = bs["mueller"], mod[f"{name}.eval"](si, wo, mueller=True, **params)
            assert np.all(np.isfinite(m)) and np.all(np.isfinite(em))
            # entries against the intensity: eval and sample turn the s/p basis to the Stokes
            # frames in different float32 roundings, ill-conditioned where the plane of
            # incidence is nearly undefined (wo near the mirror of wi at normal incidence):
            # 99% of the rows agree within 1e-5 (most within 1e-6), every row within 1e-3
            scale = np.abs(m[:, :1, :1]).max()
            pd_b = pd.reshape(n, *[1] * (m.ndim - 1))
            err = np.abs(em[ok] / pd_b[ok] - m[ok]).reshape(ok.sum(), -1).max(1) / scale
            assert np.mean(err < 1e-5) > 0.99 and err.max() < 1e-3, \
                (f"Mueller weight, theta {theta}", np.sort(err)[-5:])


# ---------------------------------------------------------------------------- furnace

def albedo(mod, name, theta, n, flux=False, **params):
    _, bs = sample(mod, name, wi_at(theta), n, rng("furnace", name, theta), **params)
    w = bs["weight"].astype(np.float64)
    if flux:
        w = w * bs["eta"][:, None].astype(np.float64) ** 2
    return w.mean(0), w.std(0) / np.sqrt(n)


WHITE = {
    "diffuse": {"reflectance": 1.0},
    "roughconductor": {},            # eta = 0, k = 1: a perfect mirror (Fresnel = 1)
    "conductor": {},
    "plastic": {"diffuse_reflectance": 1.0},
    "roughplastic": {"diffuse_reflectance": 1.0},
    "blend_example": {"reflectance": 1.0},
}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", list(WHITE))
def test_furnace_bounded(mods, name, variant):
    """albedo <= 1 + 3 sigma (+ 2e-3 for the plastics: Mitsuba's fits of the diffuse Fresnel
    reflectance are not exactly reciprocal; smooth plastic at eta = 1.49 gives 1.0011).
    Reduced grid outside rgb: two angles, one roughness."""
    mod = mods(name, variant)
    slack = 2e-3 if "plastic" in name else 0.0
    full = variant == "rgb"
    for theta in [0.0, 0.6, 1.2, 1.5] if full else [0.0, 1.2]:
        for alpha in (([0.05, 0.3, 1.0] if full else [0.3])
                      if name not in ("diffuse", "conductor", "plastic") else [None]):
            p = dict(WHITE[name], **({"alpha": alpha} if alpha else {}))
            n = 100_000 if name == "roughplastic" else 400_000
            a, s = albedo(mod, name, theta, n, **p)
            assert np.all(a <= 1 + 3 * s + slack + 1e-6), (theta, alpha, a, s)
            if name in ("diffuse", "conductor"):
                np.testing.assert_allclose(a, 1, rtol=1e-5)
            if name == "plastic":
                assert np.all(a >= 1 - 3 * s - 3e-3), (theta, a)   # lossless up to the fits


# Flux albedo of roughdielectric at theta_i = 0, 0.6, 1.2, 1.45 (outside) and pi - 0.6,
# pi - 1.2 (inside), measured with 2e5 samples:
#   GGX      alpha 0.05: 0.9997 0.9995 0.9955 0.9506 | 0.9957 0.9855
#            alpha 0.3:  0.9878 0.9806 0.9219 0.8574 | 0.8572 0.7596
#            alpha 0.7:  0.9401 0.9072 0.7368 0.5782 | 0.5866 0.5192
#            alpha 1.0:  0.8925 0.8320 0.5899 0.4173 | 0.4559 0.4074
#   Beckmann alpha 0.05: 1.0000 1.0000 1.0000 0.9773 | 1.0000 1.0000
#            alpha 0.3:  1.0000 0.9987 0.9615 0.9535 | 0.9860 0.8926
#            alpha 0.7:  0.9861 0.9746 0.9404 0.8989 | 0.7855 0.6737
#            alpha 1.0:  0.9662 0.9530 0.8658 0.7620 | 0.6639 0.5648
# The floors below are these minus a margin over theta in {0, 0.6, 1.2, pi - 0.6}.
FLOORS = {(0, 0.05): 0.99, (0, 0.3): 0.84, (0, 0.7): 0.56, (0, 1.0): 0.43,
          (1, 0.05): 0.99, (1, 0.3): 0.95, (1, 0.7): 0.76, (1, 1.0): 0.64}


FURNACE_RD_GRID = ([("rgb", *k) for k in FLOORS]
                   + [(v, d, a) for v in OTHERS for d, a in ((0, 0.05), (1, 0.3))])


@pytest.mark.parametrize("variant,dist,alpha", FURNACE_RD_GRID)
def test_furnace_roughdielectric(mods, variant, dist, alpha):
    """Flux albedo (weight * eta^2: the reflected plus transmitted energy) of roughdielectric:
    <= 1 + 3 sigma, 1 within 0.3% at alpha 0.05 and normal incidence -- but a single-scattering
    microfacet model loses the energy that the microsurface masks, a lot at high roughness
    and grazing angles (GGX more than Beckmann: longer tails); see the table above."""
    mod = mods("roughdielectric", variant)
    for theta in [0.0, 0.6, 1.2, np.pi - 0.6]:
        a, s = albedo(mod, "roughdielectric", theta, 200_000, flux=True, alpha=alpha,
                      distribution=dist)
        assert np.all(a <= 1 + 3 * s + 1e-6), (theta, a, s)   # (+ float32 rounding)
        assert np.all(a >= FLOORS[dist, alpha]), (theta, a)
        if alpha == 0.05 and theta == 0.0:
            assert np.all(a >= 0.997), a


@pytest.mark.parametrize("variant", VARIANTS)
def test_furnace_thindielectric_and_dielectric(mods, variant):
    for name in ("thindielectric", "dielectric"):
        for theta in [0.0, 1.0, 1.5, np.pi - 1.0]:
            a, s = albedo(mods(name, variant), name, theta, 100_000, flux=True)
            np.testing.assert_allclose(a, 1, rtol=1e-5)


# ---------------------------------------------------------------------------- robustness

# Cauchy dispersion: BK7; n crossing 1 between the wavelengths; only the outside dispersive
DISPERSIVE = [{"int_cauchy_b": 0.0042},
              {"int_ior": 0.99, "ext_ior": 1.0, "int_cauchy_b": 0.004},
              {"int_ior": 1.0, "ext_ior": 1.0, "ext_cauchy_b": 0.01}]

ROBUST = {
    "diffuse": [{}],
    "roughconductor": [dict(alpha=a, **p) for a in (0.0, 1e-4, 1.0)
                       for p in (GOLD, {"eta": 1.0001, "k": 0.0}, {"eta": 1.0, "k": 0.0})],
    "conductor": [GOLD, {"eta": 1.0001, "k": 0.0}, {"eta": 1.0, "k": 0.0}],
    "dielectric": [{}, {"int_ior": 1.0001, "ext_ior": 1.0}, {"int_ior": 1.0, "ext_ior": 1.0},
                   *DISPERSIVE],
    "thindielectric": [{}, {"int_ior": 1.0001, "ext_ior": 1.0}, {"int_ior": 1.0, "ext_ior": 1.0},
                       *DISPERSIVE],
    "roughdielectric": [dict(alpha=a, distribution=d, **p) for a in (1e-4, 1.0) for d in (0, 1)
                        for p in ({}, {"int_ior": 1.0001, "ext_ior": 1.0},
                                  {"int_ior": 1.0, "ext_ior": 1.0}, *DISPERSIVE)],
    "plastic": [{}, {"int_ior": 1.0001, "ext_ior": 1.0}, {"nonlinear": True},
                {"diffuse_reflectance": 0.0}],
    "roughplastic": [dict(alpha=a, distribution=d, **p) for a in (1e-4, 1.0) for d in (0, 1)
                     for p in ({}, {"int_ior": 1.0001, "ext_ior": 1.0})],
    "blend_example": [dict(alpha=a, weight=w) for a in (1e-4, 1.0) for w in (0.0, 1.0)],
}


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("name", list(ROBUST))
def test_robust(mods, name, variant):
    """No NaN or Inf (and nothing negative) for grazing directions, alpha near 0 and 1 and
    IOR near 1 (and dispersive IORs); in polarized variants every Mueller entry is finite."""
    mod = mods(name, variant)
    gen = rng("robust", name)
    n = 512
    wo = np.concatenate([sph(gen.uniform(0, np.pi, n - 6), gen.uniform(0, 2 * np.pi, n - 6)),
                         [[0, 0, 1], [1, 0, 0], [0, 1, 1e-7], [0, 0, -1], [0, 1, -1e-7],
                          [-1, 0, 0]]]).astype(f32)
    for params in ROBUST[name]:
        params = in_variant(params, variant)
        for theta in (0.0, 1e-4, 1.5, 1.5707, np.pi / 2, np.pi - 1e-4, np.pi - 1.5707):
            si = surface(tile(wi_at(theta), n))
            where = (theta, params)
            if mod.polarized:
                assert np.all(np.isfinite(mod[f"{name}.eval"](si, wo, mueller=True, **params)))
            ev = np.asarray(mod[f"{name}.eval"](si, wo, **params))
            pd = np.asarray(mod[f"{name}.pdf"](si, wo, **params))
            assert np.all(np.isfinite(ev) & (ev >= 0)), where
            assert np.all(np.isfinite(pd) & (pd >= 0)), where
            bs = mod[f"{name}.sample"](si, gen.random(n).astype(f32),
                                       gen.random((n, 2)).astype(f32), **params)
            for k in ("wo", "pdf", "weight", "eta", *(["mueller"] if mod.polarized else [])):
                assert np.all(np.isfinite(np.asarray(bs[k]))), (k, where)
            assert np.all(np.asarray(bs["weight"]) >= 0) and np.all(bs["pdf"] >= 0), where


# ---------------------------------------------------------------------------- quadratures

def test_fresnel_diffuse_reflectance_fits():
    """Mitsuba's fits of fresnel_diffuse_reflectance (plastic's internal reflectance) against
    the integral 2 int F(mu) mu dmu. (roughplastic's rough-interface integrals are Mitsuba's
    own quadratures: tests/test_tables.py compares them with Mitsuba 3.)"""
    mod = rdsl.jit("""
import bsdf.common;
fn fdr(eta: Float) -> Float { return fresnel_diffuse_reflectance(eta); }
""", target="host")
    for e in (1.2, 1.49, 2.0):
        for x in (e, 1 / e):
            mu = (np.arange(100_000) + 0.5) / 100_000
            ref = 2 * np.mean(fresnel_np(mu, x) * mu)
            assert abs(mod.fdr(np.array([x], f32))[0] - ref) < 1e-3, x
