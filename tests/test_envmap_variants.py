"""The `envmap` emitter in every variant: texels stored as each variant reads emitted colours
(linear sRGB in mono and rgb, Jakob & Hanika coefficients and a scale in the spectral ones,
as Mitsuba 3's spectral envmap), evaluated by one rdsl source.

Truths: the numpy model of Mitsuba's spectral envmap lookup (rdsl.core.spectral); a
constant-colour map equals a `constant` emitter of that colour, and lights a diffuse plane
with the analytic RHO * L (in spectral variants L is the film's sRGB of the upsampled
radiance, integrated over wavelengths); a varying map renders the same in rgb and spectral.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

import rdsl
from rdsl.core import spectral as S
from rdsl.core.color import RGB, SPECTRAL
from rdsl.runtime.render.emitters import envmap_tables
from rdsl.runtime.render.renderer import load_scene
from test_emitters import RHO, _bilinear, _envmap, scene_xml

VARIANTS = ["mono", "rgb", "spectral", "mono_polarized", "spectral_polarized"]
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


def render(tmp_path: Path, emitters: str, variant: str, spp: int = 16, **kw) -> np.ndarray:
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(emitters, **kw))
    scene = load_scene(path, variant=variant)
    img = scene.render(spp=spp, seed=3)
    assert scene.nonfinite == 0
    return img


def film_value(rgb: np.ndarray, variant: str) -> np.ndarray:
    """What the film records, in expectation, for emitted linear sRGB ``rgb``: the colour
    itself (its luminance in mono variants); in spectral ones the sRGB of its upsampled
    radiance (coefficients, scale and D65), integrated over the sampled wavelengths."""
    rgb = np.asarray(rgb, np.float64)
    if variant.startswith("mono"):
        return np.array([rgb @ LUMINANCE])
    if not variant.startswith("spectral"):
        return rgb
    u = (np.arange(1 << 16) + 0.5) / (1 << 16)
    lam, w = S.sample_wavelengths(u)
    coeffs, scale = S.illuminant_from_rgb(rgb)
    spec = S.eval_coeffs(coeffs, lam) * scale * S.d65(lam) * S.D65_NORMALIZATION
    return S.spectrum_to_srgb(spec, lam, w).mean(axis=0)


# ---- the lookup against the numpy model -------------------------------------------------

EVAL_SRC = """
import spectral;
import emitter.envmap;
fn k(u: Float, d: Vec3, W: Int, H: Int, scale: Float, ENV: [Float]) -> Vec3 {
    let w = sample_wavelengths(u);
    let m = EnvMap { width: W, height: H, scale: scale,
                     to_x: Vec3(1.0, 0.0, 0.0), to_y: Vec3(0.0, 1.0, 0.0),
                     to_z: Vec3(0.0, 0.0, 1.0), inv_x: Vec3(1.0, 0.0, 0.0),
                     inv_y: Vec3(0.0, 1.0, 0.0), inv_z: Vec3(0.0, 0.0, 1.0) };
    return to_srgb(envmap_eval(ENV, m, d) * w);
}
"""


def test_spectral_lookup_matches_mitsubas_model():
    """Mitsuba's spectral eval_spectrum: the four texels' sigmoid spectra and their scales
    are interpolated separately, multiplied, then scaled and multiplied by D65."""
    rng = np.random.default_rng(2)
    im = rng.uniform(0.0, 1.0, (9, 16, 3)) ** 2 * 6.0
    im[4, 3] = 0.0  # black: scale 0
    table, (w, h) = envmap_tables(im, SPECTRAL)
    n = 4096
    u = ((np.arange(n) + 0.5) / n).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    got = rdsl.jit(EVAL_SRC, target="avx2", variant="spectral").k(
        u, d.astype(np.float32), w, h, np.float32(1.5), table)

    # the reference: texel coefficients and scales as Mitsuba stores them, bilinear weights
    coeffs, scale = S.illuminant_from_rgb(im.reshape(-1, 3))
    coeffs, scale = coeffs.reshape(h, w, 3), scale.reshape(h, w)
    lam, wt = S.sample_wavelengths(u.astype(np.float64))
    uu = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi) - 0.5 / w
    uu -= np.floor(uu)
    x, y = uu * w, np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi * (h - 1)
    x0, y0 = np.minimum(x.astype(int), w - 1), np.minimum(y.astype(int), h - 2)
    x1, fx, fy = (x0 + 1) % w, x - x0, y - y0
    corners = [(y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)),
               (y0 + 1, x0, (1 - fx) * fy), (y0 + 1, x1, fx * fy)]
    spec = sum(S.eval_coeffs(coeffs[r, c], lam) * k[:, None] for r, c, k in corners)
    f = sum(scale[r, c] * k for r, c, k in corners)
    radiance = spec * (f * 1.5)[:, None] * S.d65(lam) * S.D65_NORMALIZATION
    np.testing.assert_allclose(got, S.spectrum_to_srgb(radiance, lam, wt), rtol=2e-4,
                               atol=1e-4)


def test_texels_are_stored_as_each_variant_reads_them():
    im = np.array([[[0.2, 0.5, 0.9], [3.0, 0.0, 1.0]]] * 3)
    rgb, _ = envmap_tables(im, RGB)
    np.testing.assert_allclose(rgb[:24].reshape(-1, 4)[:2], [[0.2, 0.5, 0.9, 1.0],
                                                             [3.0, 0.0, 1.0, 1.0]], rtol=1e-6)
    spec, _ = envmap_tables(im, SPECTRAL)
    texels = spec[:24].reshape(-1, 4)[:2].astype(np.float64)
    np.testing.assert_allclose(texels[:, 3], [1.8, 6.0], rtol=1e-6)  # 2 max(rgb), Mitsuba's
    np.testing.assert_allclose(texels[:, :3], S.rgb_to_coeffs(im[0, :2] / texels[:, 3:]),
                               rtol=1e-5, atol=1e-6)
    # the sampling tables follow luminance, the same in every variant
    np.testing.assert_array_equal(rgb[24:], spec[24:])


# ---- renders: analytic values and the two colour models ---------------------------------

COLOUR, SCALE = np.array([0.2, 0.5, 0.9]), 4.0


@pytest.mark.parametrize("variant", VARIANTS)
def test_constant_colour_envmap_equals_constant_emitter(tmp_path, variant):
    env = _envmap(tmp_path, np.tile(COLOUR, (8, 16, 1)),
                  f'<float name="scale" value="{SCALE}"/>')
    radiance = COLOUR * SCALE
    const = ('<emitter type="constant"><rgb name="radiance" value="'
             + ", ".join(map(str, radiance)) + '"/></emitter>')
    # seen directly: the same upsampled radiance at the same wavelengths
    direct = render(tmp_path, env, variant, plane=False)
    np.testing.assert_allclose(direct, render(tmp_path, const, variant, plane=False),
                               rtol=1e-5, atol=1e-6)
    expected = film_value(radiance, variant)
    np.testing.assert_allclose(direct.mean(axis=(0, 1)), expected, rtol=1e-2)
    # lighting a diffuse plane: RHO * L (the envmap is importance sampled, the constant not)
    lit = render(tmp_path, env, variant, spp=256).mean(axis=(0, 1))
    np.testing.assert_allclose(lit, RHO * expected, rtol=1.5e-2)


def _plane_directions(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint quadrature of the upper hemisphere in (cos theta, phi): directions, cosines."""
    z = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    return np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3), zz.reshape(-1)


def test_smooth_envmap_agrees_in_rgb_and_spectral(tmp_path):
    """A sky whose colour varies smoothly with theta and phi: both colour models give the
    irradiance of the bilinear map (the spectral one interpolates spectra and scales apart,
    as Mitsuba, which differs only at second order here)."""
    theta = np.linspace(0.0, np.pi, 16)[:, None]
    phi = (np.arange(32) + 0.5) / 32 * 2 * np.pi
    im = np.stack(np.broadcast_arrays(1.2 + np.cos(theta) + 0 * phi,
                                      1.0 + 0.6 * np.sin(2 * phi) + 0 * theta,
                                      0.8 + 0.7 * np.sin(theta) * np.cos(phi)), -1)
    env = _envmap(tmp_path, im)
    d, cos = _plane_directions(600)
    irradiance = (_bilinear(im, d) * cos[:, None]).mean(axis=0) * 2 * np.pi
    means = {}
    for variant in ("rgb", "spectral"):
        means[variant] = render(tmp_path, env, variant, spp=512).mean(axis=(0, 1))
        np.testing.assert_allclose(means[variant], RHO / math.pi * irradiance, rtol=1.5e-2)
    np.testing.assert_allclose(means["spectral"], means["rgb"], rtol=1.5e-2)


def test_saturated_envmap_in_spectral_follows_mitsuba(tmp_path):
    """Random saturated texels: bilinear interpolation of spectra and scales apart (Mitsuba's
    eval_spectrum) is not that of the RGB values, and the render follows the former."""
    rng = np.random.default_rng(1)
    im = rng.uniform(0, 1, (16, 32, 3)) ** 2 * 3
    h, w = im.shape[:2]
    coeffs, scale = S.illuminant_from_rgb(im.reshape(-1, 3))
    coeffs, scale = coeffs.reshape(h, w, 3), scale.reshape(h, w)
    d, cos = _plane_directions(120)
    uu = np.arctan2(d[:, 0], -d[:, 2]) / (2 * np.pi) - 0.5 / w
    uu -= np.floor(uu)
    x, y = uu * w, np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi * (h - 1)
    x0, y0 = np.minimum(x.astype(int), w - 1), np.minimum(y.astype(int), h - 2)
    x1, fx, fy = (x0 + 1) % w, x - x0, y - y0
    corners = [(y0, x0, (1 - fx) * (1 - fy)), (y0, x1, fx * (1 - fy)),
               (y0 + 1, x0, (1 - fx) * fy), (y0 + 1, x1, fx * fy)]
    u = (np.arange(64) + 0.5) / 64
    lams, weights = S.sample_wavelengths(u)
    mitsuba = np.zeros(3)
    for lam, wt in zip(lams, weights):
        lam = np.broadcast_to(lam, (len(d), 4))
        spec = sum(S.eval_coeffs(coeffs[r, c], lam) * k[:, None] for r, c, k in corners)
        f = sum(scale[r, c] * k for r, c, k in corners)
        radiance = spec * f[:, None] * S.d65(lam) * S.D65_NORMALIZATION
        srgb = S.spectrum_to_srgb(radiance, lam, np.broadcast_to(wt, (len(d), 4)))
        mitsuba += (srgb * cos[:, None]).mean(axis=0) * 2 * np.pi / len(u)
    rgb = (_bilinear(im, d) * cos[:, None]).mean(axis=0) * 2 * np.pi
    assert np.abs(mitsuba / rgb - 1.0).max() > 0.02  # the two interpolations differ here
    got = render(tmp_path, _envmap(tmp_path, im), "spectral", spp=512).mean(axis=(0, 1))
    np.testing.assert_allclose(got, RHO / math.pi * mitsuba, rtol=1e-2)


def test_spectral_envmap_generic_build_equals_specialized(tmp_path):
    rng = np.random.default_rng(4)
    env = _envmap(tmp_path, rng.uniform(0, 1, (8, 16, 3)) * 3)
    point = ('<emitter type="point"><point name="position" x="0" y="0" z="1"/>'
             '<rgb name="intensity" value="1, 2, 3"/></emitter>')
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(env + point))
    a = load_scene(path, variant="spectral")
    b = load_scene(path, variant="spectral", specialize=False)
    assert b.prm.size > 0
    np.testing.assert_allclose(a.render(spp=4, seed=3), b.render(spp=4, seed=3), atol=1e-5)
