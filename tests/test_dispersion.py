"""Dispersive dielectrics: Cauchy's equation n(l) = A + B / l^2 (l in um) in `dielectric`,
`thindielectric` and `roughdielectric` (stdlib/dispersion.rdsl).

1. Snell per wavelength: a refracted direction obeys Snell's law with n at the sample's hero
   wavelength (spectral variants, where `disperses()` then tells the integrator to end the
   other three), or at 589.3 nm (mono, rgb), against numpy's Fresnel equations;
2. unbiased: over the wavelengths and the lobe choices, the film's estimate of the weight,
   terminated as the path integrator does it (x (4, 0, 0, 0)), equals the analytic
   per-wavelength Fresnel reflectance / transmittance, in wavelength bands (a paired test:
   against numpy's per-wavelength value at the same wavelengths); the thin sheet, which
   keeps all four wavelengths, is unbiased at every wavelength;
3. B = 0 is the non-dispersive BSDF exactly (spectral and mono against rgb, bit for bit);
4. the rough interface: chi-square of sample() against pdf() at a fixed hero wavelength,
   weight = eval / pdf, and the flux albedo <= 1;
5. scenes: `int_cauchy_b` / `ext_cauchy_b` reach the plugins, bad values are errors, an rgb
   render warns that it has no dispersion; a dispersive glass sphere (or a blendbsdf of
   dispersive ones) in a white furnace renders without NaN, as white as the light within
   the noise; and the path and direct integrators' termination of the secondary wavelengths
   (once per path, x4) leaves the expected image of a glass whose eta is the same at every
   wavelength (both sides dispersive alike) unchanged.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _bsdf_harness import VARIANTS, Harness
from rdsl.compiler.diagnostics import CompileError
from rdsl.core import spectral as S
from rdsl.runtime.testkit.chi2 import chi2_directions
from test_bsdf_plugins import fresnel_np, pdf_fn, rng, sample, surface, tile, wi_at

f32 = np.float32
A, B, EXT = 1.5046, 0.00420, 1.000277  # BK7 (Cauchy's A and B in um^2), Mitsuba's air
D_LINE = 589.3
SPECTRAL = ("spectral", "spectral_polarized")


@pytest.fixture(scope="module")
def mods():
    cache: dict[tuple[str, str], Harness] = {}

    def get(name: str, variant: str) -> Harness:
        if (name, variant) not in cache:
            cache[name, variant] = Harness(name, variant)
        return cache[name, variant]
    return get


def cauchy(a: float, b: float, lam_nm) -> np.ndarray:
    return a + b / (np.asarray(lam_nm, np.float64) * 1e-3) ** 2


def hero_eta(mod: Harness, n: int, ul=None, a=A, b=B) -> np.ndarray:
    """eta = n_int / n_ext per row: at the hero wavelength, or at 589.3 nm."""
    lam = mod.wavelengths(n, ul)
    at = np.full(n, D_LINE) if lam is None else lam[:, 0].astype(np.float64)
    return cauchy(a, b, at) / EXT


# ---------------------------------------------------------------------------- 1. Snell

@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("theta", [0.6, 1.3, np.pi - 0.4])
def test_snell_per_wavelength(mods, variant, theta):
    mod, n = mods("dielectric", variant), 100_000
    wi = wi_at(theta)
    _, bs = sample(mod, "dielectric", wi, n, rng("snell", variant, theta), int_cauchy_b=B)
    eta = hero_eta(mod, n)
    eta_it = eta if wi[2] > 0 else 1 / eta
    f = fresnel_np(wi[2], eta)
    refl = bs["wo"][:, 2] * wi[2] > 0
    t = ~refl
    # Snell's law in the plane of incidence, per row's own IOR
    np.testing.assert_allclose(bs["wo"][t, :2], -wi[None, :2] / eta_it[t, None], atol=2e-6)
    np.testing.assert_allclose(np.linalg.norm(bs["wo"][t], axis=1), 1, atol=1e-6)
    np.testing.assert_allclose(bs["eta"][t], eta_it[t], rtol=1e-6)
    np.testing.assert_allclose(bs["pdf"], np.where(refl, f, 1 - f), rtol=2e-4)
    np.testing.assert_allclose(bs["wo"][refl], tile([-wi[0], -wi[1], wi[2]], refl.sum()),
                               atol=1e-6)
    assert abs(refl.mean() - f.mean()) < 5 * np.sqrt(f.mean() * (1 - f.mean()) / n)
    # the weight: 1 (reflection) or 1 / eta_it^2 (the hero's, in every entry)
    w = np.where(refl, 1.0, 1 / eta_it ** 2)[:, None]
    got = bs["weight"].reshape(n, -1)
    np.testing.assert_allclose(got, np.broadcast_to(w, got.shape), rtol=1e-5)
    spread = np.ptp(np.linalg.norm(bs["wo"][t, :2], axis=1))
    assert mod.disperses(int_cauchy_b=B) == (variant in SPECTRAL)
    assert not mod.disperses(int_cauchy_b=0.0)
    if variant in SPECTRAL:
        assert spread > 1e-3  # the directions do depend on the wavelength
    else:
        assert spread < 1e-6  # one IOR: n at the sodium D line
    if "mueller" in bs:
        assert np.all(np.isfinite(bs["mueller"]))


def test_plugin_on_its_own_has_no_dispersion():
    """The dielectric compiled on its own in a spectral variant has no wavelengths (`if const
    wavelengths` is false there): it refracts by n at 589.3 nm, as mono and rgb do."""
    import rdsl
    from rdsl.compiler.sources import STDLIB

    mod = rdsl.jit(str(STDLIB / "bsdf" / "dielectric.rdsl"), target="host", variant="spectral")
    n, wi = 4096, wi_at(0.8)
    bs = sample(mod, "dielectric", wi, n, rng("alone"), int_cauchy_b=B)[1]
    t = bs["wo"][:, 2] < 0
    eta = cauchy(A, B, D_LINE) / EXT
    np.testing.assert_allclose(bs["wo"][t, :2], np.broadcast_to(-wi[:2] / eta, (t.sum(), 2)),
                               atol=2e-6)
    assert t.any() and not t.all()


# ---------------------------------------------------------------------------- 2. unbiased

BANDS = {"all": (0, 1e9), "blue": (0, 480), "red": (620, 1e9)}


def _film_estimates(mod, name, theta, n, key, **params):
    """Per row: the lambda-weighted film estimate (1/4) sum_j g(l_j) w_j x_j of the kernel's
    reflected and transmitted flux weights x, terminated as the path integrator does when the
    BSDF disperses; in every band g."""
    gen = rng("unbiased", key, name, theta)
    ul = gen.random(n).astype(f32)
    wi = wi_at(theta)
    si = surface(tile(wi, n))
    bs = mod[f"{name}.sample"](si, gen.random(n).astype(f32), gen.random((n, 2)).astype(f32),
                               ul=ul, **params)
    lam = mod.wavelengths(n, ul).astype(np.float64)
    w = 1.0 / S.wavelength_pdf(lam)  # what sample_wavelengths returns, as the film applies it
    flux = bs["weight"].astype(np.float64) * bs["eta"][:, None].astype(np.float64) ** 2
    if mod.disperses(**params):
        flux = flux * [4, 0, 0, 0]
    refl = (bs["wo"][:, 2] * wi[2] > 0)[:, None]
    out = {}
    for band, (lo, hi) in BANDS.items():
        g = w * ((lam >= lo) & (lam < hi))
        out[band] = (0.25 * np.sum(g * flux * refl, 1), 0.25 * np.sum(g * flux * ~refl, 1), g)
    return lam, out


@pytest.mark.parametrize("variant", SPECTRAL)
@pytest.mark.parametrize("theta", [0.9, np.pi - 0.6])
def test_dielectric_dispersion_unbiased(mods, variant, theta):
    """E[film estimate of the reflected / transmitted flux] = the integral of g F(l) and
    g (1 - F(l)) with F at each wavelength's own IOR: the hero's x4 stands for the ended
    wavelengths. (pi - 0.6: from inside, beyond the critical angle for some wavelengths.)"""
    mod, n = mods("dielectric", variant), 400_000
    b = 0.03  # strong dispersion: F differs markedly across the spectrum
    assert mod.disperses(int_cauchy_b=b)
    lam, est = _film_estimates(mod, "dielectric", theta, n, variant, int_cauchy_b=b)
    f = fresnel_np(np.cos(theta), cauchy(A, b, lam) / EXT)
    for band, (x_r, x_t, g) in est.items():
        for x, ref in ((x_r, 0.25 * np.sum(g * f, 1)), (x_t, 0.25 * np.sum(g * (1 - f), 1))):
            d = x - ref  # paired: the same wavelengths
            assert abs(d.mean()) < 5 * d.std() / np.sqrt(n) + 1e-9, (band, d.mean(), d.std())
    # the terminated estimate differs from the per-wavelength one (the test can fail)
    x_r, _, g = est["blue"]
    assert np.std(x_r - 0.25 * np.sum(g * f, 1)) > 0


@pytest.mark.parametrize("variant", SPECTRAL)
def test_thindielectric_dispersion_per_wavelength(mods, variant):
    """The thin sheet keeps the four wavelengths: E[weight_j; reflected] = R'(l_j) for every
    j, with R' = 2R / (1 + R) at that wavelength's IOR."""
    mod, n = mods("thindielectric", variant), 300_000
    b, theta = 0.03, 1.2
    ul = rng("thin-ul").random(n).astype(f32)
    wi = wi_at(theta)
    si = surface(tile(wi, n))
    gen = rng("thin-disp", variant)
    bs = mod["thindielectric.sample"](si, gen.random(n).astype(f32),
                                      gen.random((n, 2)).astype(f32), ul=ul, int_cauchy_b=b)
    lam = mod.wavelengths(n, ul).astype(np.float64)
    r = fresnel_np(np.cos(theta), cauchy(A, b, lam) / EXT)
    r = 2 * r / (1 + r)
    refl = (bs["wo"][:, 2] > 0)[:, None]
    assert not mod.disperses(int_cauchy_b=b)  # all four wavelengths live on
    assert np.all(bs["weight"] > 0) and np.all(bs["weight"] < 4)
    for x, ref in ((bs["weight"] * refl, r), (bs["weight"] * ~refl, 1 - r)):
        d = x - ref
        assert np.all(np.abs(d.mean(0)) < 5 * d.std(0) / np.sqrt(n)), (d.mean(0), d.std(0))
    np.testing.assert_allclose(bs["pdf"], np.where(refl[:, 0], r.mean(1), 1 - r.mean(1)),
                               rtol=2e-4)


# ---------------------------------------------------------------------------- 3. B = 0

@pytest.mark.parametrize("name,params", [("dielectric", {}), ("thindielectric", {}),
                                         ("roughdielectric", {"alpha": 0.3})])
def test_no_dispersion_is_exact(mods, name, params):
    """B = 0: the spectral variants compute what the ones without wavelengths compute with
    eta = int_ior / ext_ior, to the bit: spectral and mono as rgb, spectral_polarized as
    mono_polarized (whose Mueller arithmetic rounds differently from rgb's plain weight)."""
    n = 20_000
    wi = wi_at(np.pi - 0.7 if name == "roughdielectric" else 0.7)
    for ref_variant, variant in (("rgb", "mono"), ("rgb", "spectral"),
                                 ("mono_polarized", "spectral_polarized")):
        ref = sample(mods(name, ref_variant), name, wi, n, rng("b0", name), int_cauchy_b=0.0,
                     **params)[1]
        bs = sample(mods(name, variant), name, wi, n, rng("b0", name), int_cauchy_b=0.0,
                    **params)[1]
        for k in ("wo", "pdf", "eta", "delta"):
            np.testing.assert_array_equal(bs[k], ref[k], err_msg=f"{variant} {k}")
        np.testing.assert_array_equal(bs["weight"], np.broadcast_to(ref["weight"][:, :1],
                                                                   bs["weight"].shape),
                                      err_msg=variant)
        if "mueller" in bs:
            np.testing.assert_array_equal(bs["mueller"], np.broadcast_to(
                ref["mueller"][..., None], bs["mueller"].shape), err_msg=variant)


# ---------------------------------------------------------------------------- 4. rough

@pytest.mark.parametrize("theta", [0.8, np.pi - 0.8])
def test_roughdielectric_dispersion(mods, theta):
    mod, n = mods("roughdielectric", "spectral"), 400_000
    params = {"alpha": 0.3, "int_cauchy_b": 0.03}
    wi = wi_at(theta)
    # one hero wavelength for every row: pdf() is then one density
    ul = 0.8
    si = surface(tile(wi, n))
    gen = rng("rough-disp", theta)
    bs = mod["roughdielectric.sample"](si, gen.random(n).astype(f32),
                                       gen.random((n, 2)).astype(f32), ul=ul, **params)
    valid = bs["pdf"] > 0
    pdf = pdf_fn(mod, "roughdielectric", wi, ul=ul, **params)
    p = chi2_directions(bs["wo"], valid, pdf, n, lower=True, res=(60, 40))
    assert p > 1e-3, p
    # weight = eval / pdf, on the hero only
    ev = np.asarray(mod["roughdielectric.eval"](si, bs["wo"], ul=ul, **params))
    pd = np.asarray(mod["roughdielectric.pdf"](si, bs["wo"], ul=ul, **params))
    # (pdf() recomputes the half vector from wo: float32 rounding, a few rows near grazing)
    rel = np.abs(pd[valid] / bs["pdf"][valid] - 1)
    assert np.mean(rel < 1e-3) > 0.9999 and rel.max() < 1e-2, rel.max()
    np.testing.assert_allclose(ev[valid] / pd[valid, None], bs["weight"][valid], rtol=1e-4,
                               atol=1e-7)
    assert mod.disperses(**params)
    np.testing.assert_array_equal(bs["weight"], bs["weight"][:, :1] + 0 * bs["weight"])
    # the refracted samples obey eta at the hero wavelength: BsdfSample.eta
    lam0 = mod.wavelengths(1, ul)[0, 0]
    eta = cauchy(A, 0.03, lam0) / EXT
    t = valid & (bs["wo"][:, 2] * wi[2] < 0)
    np.testing.assert_allclose(bs["eta"][t], eta if wi[2] > 0 else 1 / eta, rtol=1e-6)
    # flux albedo of the hero <= 1
    flux = bs["weight"][:, 0] * bs["eta"] ** 2
    assert flux.mean() <= 1 + 3 * flux.std() / np.sqrt(n)
    assert flux.mean() > 0.8


# ---------------------------------------------------------------------------- 5. scenes

def scene_xml(bsdf: str, res: int = 24,
              integrator: str = '<integer name="max_depth" value="64"/>') -> str:
    """A glass sphere filling most of the view, in a white furnace (a constant emitter)."""
    kind = "path" if "max_depth" in integrator else "direct"
    return f"""<scene version="3.0.0">
    <integrator type="{kind}">{integrator}</integrator>
    <sensor type="perspective"><float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/><rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
    <shape type="sphere"><float name="radius" value="1.2"/>{bsdf}</shape>
</scene>"""


GLASS = ('<bsdf type="dielectric"><string name="int_ior" value="bk7"/>'
         '<float name="int_cauchy_b" value="{b}"/></bsdf>')
# a blendbsdf of two lossless dispersive BSDFs: the mixture asks its leaves
BLEND = ('<bsdf type="blendbsdf"><float name="weight" value="0.4"/>' + GLASS
         + '<bsdf type="thindielectric"><float name="int_cauchy_b" value="{b}"/></bsdf></bsdf>')


def test_scene_parameters_and_errors(tmp_path):
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "s.xml"
    path.write_text(scene_xml(GLASS.format(b=0.0042)))
    with pytest.warns(UserWarning, match="only spectral variants render"):
        scene = load_scene(path)
    assert scene.bsdfs[0].params["int_cauchy_b"] == 0.0042
    assert scene.bsdfs[0].params["int_ior"] == A
    for bad in ("-0.001", "4200", "nan"):
        path.write_text(scene_xml(GLASS.format(b=bad)))
        with pytest.raises(CompileError, match="Cauchy's B term is in um"):
            load_scene(path, variant="spectral")


@pytest.mark.parametrize("variant,bsdf", [("spectral", GLASS), ("rgb", GLASS),
                                          ("spectral", BLEND)], ids=["spectral", "rgb", "blend"])
def test_dispersive_sphere_in_furnace(tmp_path, variant, bsdf):
    """A lossless glass sphere in uniform white light is invisible: every pixel's expected
    value is the light's (1, 1, 1), with or without dispersion (spectral: strongly dispersive,
    B = 0.05, so that a path crosses several dispersive interfaces and must end its secondary
    wavelengths once only; rgb: its IOR at 589.3 nm)."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "f.xml"
    path.write_text(scene_xml(bsdf.format(b=0.05)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_scene(path, variant=variant)
    assert any("dispersive" in str(w.message) for w in caught) == (variant == "rgb")
    img = scene.render(spp=64, seed=2)[..., :3].astype(np.float64)
    assert scene.nonfinite == 0 and np.all(np.isfinite(img))
    if variant == "rgb":  # (a single wavelength's sRGB may be negative: out of gamut)
        assert np.all(img >= 0)
    per_pixel = img.reshape(-1, 3)
    mean, sem = per_pixel.mean(0), per_pixel.std(0) / np.sqrt(len(per_pixel))
    # noise plus the film's white point (test_spectral: 5e-3) plus the paths cut at depth 64
    # (a bound on the noise too: a biased estimator may be wild rather than off)
    assert np.all(sem < 0.03) and np.all(np.abs(mean - 1) < 5 * sem + 1e-2), (mean, sem)
    if variant == "spectral":
        assert per_pixel.std(0).max() > 0.05  # dispersion: colour noise where the sphere is


def sphere_pixels(res: int = 24, inner: float = 1.0) -> np.ndarray:
    """The pixels of scene_xml's view whose centre ray passes within `inner` of the sphere's
    centre (radius 1.2: well inside its outline)."""
    c = (np.arange(res) + 0.5) / res * 2 - 1
    x, y = np.meshgrid(c * np.tan(np.radians(15)), -c * np.tan(np.radians(15)))
    d = np.stack([x, y, -np.ones_like(x)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    dist = np.linalg.norm(np.cross(d, [0.0, 0.0, 5.0]), axis=-1)  # of the centre, from the ray
    return (dist < inner).ravel()


# dispersive on both sides alike: eta = (1.5 + 0.03 / l^2) / (1 + 0.02 / l^2) = 1.5 at every
# wavelength, yet the BSDF disperses (B != 0), so spectral paths end their secondary
# wavelengths; the expected image is that of eta = 1.5 without dispersion
MATCHED = ('<bsdf type="dielectric"><float name="int_ior" value="1.5"/>'
           '<float name="ext_ior" value="1.0"/><float name="int_cauchy_b" value="{b}"/>'
           '<float name="ext_cauchy_b" value="{b_ext}"/></bsdf>')


@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_terminating_wavelengths_is_unbiased(tmp_path, integrator):
    """Ending the secondary wavelengths (x 4 on the hero, once per path) leaves the expected
    image unchanged: MATCHED with B = 0.03 / 0.02 against B = 0, over the sphere's pixels.
    The direct integrator sees the furnace in the sphere's reflection only (refracted rays
    meet the sphere again, not the light): the sphere's mean Fresnel reflectance."""
    from rdsl.runtime.render.renderer import load_scene

    means, on = [], sphere_pixels()
    spec = "" if integrator == "direct" else '<integer name="max_depth" value="64"/>'
    for b, b_ext in ((0.03, 0.02), (0.0, 0.0)):
        path = tmp_path / f"d{b}.xml"
        path.write_text(scene_xml(MATCHED.format(b=b, b_ext=b_ext), integrator=spec))
        scene = load_scene(path, variant="spectral")
        img = scene.render(spp=64, seed=3 if b else 4)[..., :3].astype(np.float64)
        assert scene.nonfinite == 0 and np.all(np.isfinite(img))
        img = img.reshape(-1, 3)[on]
        means.append((img.mean(0), img.std(0) / np.sqrt(len(img))))
    (m1, s1), (m0, s0) = means
    assert np.all(s1 < 0.05) and np.all(np.abs(m1 - m0) < 5 * np.hypot(s1, s0) + 2e-3), \
        (m1, m0, s1, s0)
    if integrator == "direct":  # 2 int F(mu) mu dmu = 0.092 for eta = 1.5 over the disk,
        assert np.all(m0 > 0.03) and np.all(m0 < 0.09), m0  # less well inside the rim
    else:
        assert np.all(np.abs(m0 - 1) < 5 * s0 + 1e-2), m0  # the furnace
