"""`spectral_polarized` against Mitsuba 3's `scalar_spectral_polarized` (which needs no LLVM,
so this runs wherever the `mitsuba` package is installed; skipped without it).

1. A render by the `stokes` integrator: tests/test_polarized.py's scene of a conductor, a
   glass plane and two polarizers, with a gold conductor (tabulated eta and k) under a
   coloured sky, so that S0..S3 differ between the colour channels.  Stokes images per block
   of pixels, every colour channel.
2. The combinators `twosided` and `blendbsdf` around polarizing BSDFs, flattened into rdsl's
   `mixture` (runtime/render/bsdfs.py) and called through the scene dispatch
   (tests/_bsdf_harness.py's SceneBsdfs): the Mueller matrices of eval() and sample() at
   every one of the four wavelengths, seen from both sides.  Conductors here have
   wavelength-dependent `<spectrum>` values, which rdsl evaluates as Mitsuba does: the linear
   interpolant of their knots, exactly (any knots; these lie on multiples of 5 nm, which the
   5 nm resampling rdsl once did left exact).

Mitsuba's BSDFs return matrices in the local frame between the implicit bases
stokes_basis(-wo) and stokes_basis(wi), as rdsl's do (tests/test_polarized.py).  Its twosided
mirrors wi and wo through the surface and returns the nested matrix unchanged; so does rdsl.
"""

from __future__ import annotations

import numpy as np
import pytest
from _bsdf_harness import SceneBsdfs
from test_polarized_bsdfs_mitsuba import (
    STOKES_SCENE,
    _block_means,
    _directions,
    _rel_err,
    _surfaces,
    mitsuba_polarized,
)

f32 = np.float32


@pytest.fixture(scope="module")
def mi():
    yield from mitsuba_polarized()


# ---------------------------------------------------------------------- a render

GOLD_UNDER_AMBER = (STOKES_SCENE
                    .replace('<float name="eta" value="0.2"/><float name="k" value="3.9"/>',
                             '<string name="material" value="Au"/>')
                    .replace('<rgb name="radiance" value="1, 1, 1"/>',
                             '<rgb name="radiance" value="1, 0.7, 0.4"/>'))
STOKES = [f"S{i}.{c}" for i in range(4) for c in "RGB"]


def test_spectral_stokes_render_matches_mitsuba(mi, tmp_path):
    """rdsl (`spectral_polarized`) and Mitsuba (`scalar_spectral_polarized`), 1024 spp each:
    every Stokes channel agrees per 4x4-pixel block (an 8x8 grid) within 0.012.  The noise,
    measured: two Mitsuba renders with different seeds differ by up to 0.0051 per block, rdsl
    against Mitsuba by up to 0.0057 (for two pairs of seeds), and by 0.0006 at 8192 spp, where
    Mitsuba's own noise dominates.  The scene has S0 up to 1, |S1| 0.28, |S2| 0.39 and |S3|
    0.14 (red) against 0.02 (blue), so a sign, frame or wavelength error is far outside."""
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "stokes.xml"
    path.write_text(GOLD_UNDER_AMBER)
    scene = load_scene(path, variant="spectral_polarized")
    assert scene.channel_names == ["R", "G", "B", *STOKES]
    img = scene.render(spp=1024, seed=0)

    ref_scene = mi.load_file(str(path))
    ref = np.array(mi.render(ref_scene, spp=1024, seed=0))
    names = [f.name for f in ref_scene.sensors()[0].film().bitmap().struct_()]
    assert names == ["R", "G", "B", *STOKES] and ref.shape == img.shape

    worst = 0.0
    for c, name in enumerate(STOKES, start=3):
        ours, theirs = _block_means(img[..., c], 8), _block_means(ref[..., c], 8)
        np.testing.assert_allclose(ours, theirs, atol=0.012, err_msg=name)
        worst = max(worst, float(np.abs(ours - theirs).max()))
    print(f"max block difference over S0..S3 x RGB: {worst:.4f}")

    def theirs(name: str) -> np.ndarray:
        return _block_means(ref[..., names.index(name)], 8)

    assert np.abs(theirs("S1.R")).max() > 0.2 and np.abs(theirs("S2.R")).max() > 0.3
    assert np.abs(theirs("S3.R")).max() > 0.1  # the gold's phase shift: elliptical light
    assert np.abs(theirs("S3.R") - theirs("S3.B")).max() > 0.08  # and it depends on colour


# ---------------------------------------------------------------------- combinators

# Two conductors whose eta and k vary with the wavelength (knots on multiples of 5 nm)
METAL_A = ('<spectrum name="eta" value="360:1.6, 450:1.3, 520:0.6, 600:0.2, 830:0.15"/>'
           '<spectrum name="k" value="360:1.9, 500:1.8, 600:3.0, 830:5.5"/>')
METAL_B = ('<spectrum name="eta" value="360:1.3, 550:1.0, 600:0.3, 830:0.25"/>'
           '<spectrum name="k" value="360:1.7, 500:2.5, 650:3.7, 830:5.2"/>')
CONDUCTOR = f'<bsdf type="conductor">{METAL_A}</bsdf>'
ROUGH = ('<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
         f'<float name="alpha_u" value="0.15"/><float name="alpha_v" value="0.4"/>{METAL_B}'
         '</bsdf>')
DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf>'
GLASS = '<bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf>'


def _twosided(*kids: str) -> str:
    return f'<bsdf type="twosided">{"".join(kids)}</bsdf>'


def _blend(w: float, a: str, b: str) -> str:
    return f'<bsdf type="blendbsdf"><float name="weight" value="{w}"/>{a}{b}</bsdf>'


# name -> (XML, blendbsdf weight for the random-number mapping, the nested delta BSDF whose
# samples rdsl's are compared with when Mitsuba's own blend differs (see below), its share)
COMBINATORS = {
    "twosided(conductor)": (_twosided(CONDUCTOR), 0.0, None, 1.0),
    "twosided(rough, diffuse)": (_twosided(ROUGH, DIFFUSE), 0.0, None, 1.0),
    "blend(conductor, glass)": (_blend(0.3, CONDUCTOR, GLASS), 0.3, None, 1.0),
    "blend(rough, diffuse)": (_blend(0.4, ROUGH, DIFFUSE), 0.4, None, 1.0),
    "twosided(blend(diffuse, rough))": (_twosided(_blend(0.7, DIFFUSE, ROUGH)), 0.0, None, 1.0),
    "blend(conductor, diffuse)": (_blend(0.6, CONDUCTOR, DIFFUSE), 0.6, CONDUCTOR, 0.4),
}
SMOOTH = [k for k in COMBINATORS if "rough" in k or "diffuse" in k]
GRID = _directions([5, 30, 56.3, 80], [0.3, 2.0, -1.2])


@pytest.fixture(scope="module")
def combinators(tmp_path_factory):
    """Every COMBINATORS entry on a shape of one scene, compiled in `spectral_polarized`."""
    body = "".join(f'<shape type="sphere">{xml}</shape>' for xml, *_ in COMBINATORS.values())
    path = tmp_path_factory.mktemp("combinators") / "bsdfs.xml"
    path.write_text(f'<scene version="3.0.0">{body}</scene>')
    return SceneBsdfs(path, "spectral_polarized")


def _load(mi, xml: str):
    return mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))


def _mi_si(mi, wi: np.ndarray, wavelengths: np.ndarray):
    si = mi.SurfaceInteraction3f()
    si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
    si.wavelengths = [float(x) for x in wavelengths]
    si.wi = [float(x) for x in wi]
    return si


def _mi_matrix(m) -> np.ndarray:
    return np.array(m).astype(np.float64)  # [row, column, wavelength]


def _err(ours: np.ndarray, theirs: np.ndarray) -> float:
    """_rel_err at each wavelength, the largest."""
    return max(_rel_err(ours[..., c], theirs[..., c]) for c in range(ours.shape[-1]))


@pytest.mark.parametrize("name", SMOOTH)
def test_combinator_eval_matches_mitsuba(mi, combinators, name):
    """eval() and pdf() over every pair of a direction grid, light from above and from
    below, wo on either side: Mitsuba's Mueller matrix at each of the row's wavelengths."""
    bsdf = combinators[list(COMBINATORS).index(name)]
    ref = _load(mi, COMBINATORS[name][0])
    ctx = mi.BSDFContext()
    grid = np.concatenate([GRID, -GRID])
    wi = np.repeat(grid, len(grid), axis=0).astype(f32)
    wo = np.tile(grid, (len(grid), 1)).astype(f32)
    n = len(wi)
    ours = bsdf.eval(_surfaces(wi), wo, mueller=True).astype(np.float64)
    pdf = bsdf.pdf(_surfaces(wi), wo)
    lam = bsdf.wavelengths(n)
    worst = 0.0
    for i in range(n):
        si, d = _mi_si(mi, wi[i], lam[i]), [float(x) for x in wo[i]]
        theirs = _mi_matrix(ref.eval(ctx, si, d))
        err = _err(ours[i], theirs)
        assert err < 2e-6, (name, wi[i], wo[i], ours[i], theirs)
        assert pdf[i] == pytest.approx(ref.pdf(ctx, si, d), rel=1e-5, abs=1e-7)
        worst = max(worst, err)
    below = wi[:, 2] < 0
    if name.startswith("twosided"):  # a twosided reflects light from below too
        assert np.abs(ours[below, 0, 0]).max() > 0.05
    if "rough" in name:  # the rough conductor polarizes
        assert np.abs(ours[:, 1:, :]).max() > 0.02
    print(f"{name}: {n} pairs x 4 wavelengths, max |dM| / max(1, M00) = {worst:.2e}")


@pytest.mark.parametrize("name", list(COMBINATORS))
def test_combinator_sample_matches_mitsuba(mi, combinators, name):
    """sample() from both sides, for random numbers u1 that reach every nested BSDF.

    A delta sample (a smooth conductor or glass) is compared with Mitsuba's for the same
    nested random number: Mitsuba's blendbsdf samples its *second* BSDF when u1 <= weight,
    rdsl's its first when u1 < 1 - weight, both rescaling u1 to the chosen share, so Mitsuba's
    u1 is rdsl's plus the weight, modulo 1.  Its pdf is the nested one times the BSDF's share
    in both.  A smooth sample is compared with Mitsuba's eval / pdf at its direction (the
    microfacet samplers map random numbers differently).

    Mitsuba 3.9's blendbsdf is biased for a delta sample next to a smooth BSDF (it divides
    share x delta weight + smooth eval(wo) by share + smooth pdf(wo), mixing a probability
    with a density): for blend(conductor, diffuse) at 25 degrees its mean sample weight is
    0.625 against the albedo 0.681.  There rdsl's delta samples are compared with the nested
    conductor of Mitsuba itself: the conductor's weight, and its pdf times its share."""
    xml, weight, nested, share = COMBINATORS[name]
    bsdf = combinators[list(COMBINATORS).index(name)]
    ref = _load(mi, xml)
    delta_ref = _load(mi, nested) if nested else ref
    ctx = mi.BSDFContext()
    gen = np.random.default_rng(11)
    wi = np.concatenate([GRID, -GRID]).astype(f32)
    n = len(wi)
    lam = bsdf.wavelengths(n)
    counts = {"delta": 0, "smooth": 0}
    worst = 0.0
    for u1 in (0.05, 0.35, 0.62, 0.69, 0.75, 0.97):
        u2 = gen.random((n, 2)).astype(f32)
        bs = bsdf.sample(_surfaces(wi), np.full(n, u1, f32), u2)
        for i in range(n):
            si = _mi_si(mi, wi[i], lam[i])
            if bs["delta"][i]:
                mbs, mw = delta_ref.sample(ctx, si, (u1 + weight) % 1.0, u2[i].tolist())
                if mbs.pdf == 0.0:  # a one-sided conductor seen from below
                    assert bs["pdf"][i] == 0.0 or np.abs(bs["mueller"][i]).max() == 0.0
                    continue
                np.testing.assert_allclose(bs["wo"][i], np.array(mbs.wo), atol=1e-5)
                assert bs["pdf"][i] == pytest.approx(mbs.pdf * share, rel=1e-5)
                theirs, kind = _mi_matrix(mw), "delta"
            elif bs["pdf"][i] > 0.0:
                d = [float(x) for x in bs["wo"][i]]
                pdf = ref.pdf(ctx, si, d)
                assert bs["pdf"][i] == pytest.approx(pdf, rel=1e-4)
                theirs, kind = _mi_matrix(ref.eval(ctx, si, d)) / pdf, "smooth"
            else:
                continue
            err = _err(bs["mueller"][i].astype(np.float64), theirs)
            assert err < 2e-5, (name, kind, wi[i], u1, bs["mueller"][i], theirs)
            worst, counts[kind] = max(worst, err), counts[kind] + 1
    assert counts["delta"] >= (n if "conductor" in name else 0)
    assert counts["smooth"] >= (n if name in SMOOTH else 0)
    print(f"{name}: {counts}, max |dM| / max(1, M00) = {worst:.2e}")
