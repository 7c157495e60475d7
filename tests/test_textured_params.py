"""Textures on Float parameters (the roughness `alpha`, `alpha_u`, `alpha_v`) and on an area
emitter's `radiance`.

A Float parameter reads the texture's one-value lookup, Mitsuba's `eval_1`, whose convention
depends on the texture: a bitmap gives the luminance of its linear RGB (the value itself for
a grey image); a checkerboard of rgb colours gives the one value of Mitsuba's `srgb` texture,
the mean of the channels in rgb variants, the luminance in mono and the mean of the
upsampled spectrum in spectral (`test_one_values_are_mitsubas` checks these constants against
Mitsuba 3 itself).  The scene: a unit rectangle filling the
view of a camera straight above it, lit by a point light, so a pixel's estimate is
deterministic given its samples and every pixel sees one region of a 2x2 checkerboard (or a
2x2 bitmap with nearest filtering).  With the same seed, each pixel of the textured render
must equal the same pixel of the render whose constant parameter is that region's value.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from rdsl.compiler.diagnostics import CompileError
from rdsl.core import spectral as S
from rdsl.core.spectral import srgb_model_mean
from rdsl.runtime.render.image import write_exr
from rdsl.runtime.render.renderer import load_scene

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
C0, C1 = np.array([0.1, 0.6, 0.2]), np.array([0.5, 0.2, 0.9])
A0, A1 = float(C0 @ LUMINANCE), float(C1 @ LUMINANCE)  # 0.4650, 0.3144: a bitmap's
M0, M1 = float(C0.mean()), float(C1.mean())  # 0.3, 0.5333: a checkerboard's in rgb variants
S0, S1 = (float(x) for x in srgb_model_mean([C0, C1]))  # a checkerboard's in spectral
FOV = 2 * math.degrees(math.atan(1 / 4))  # the rectangle [-1, 1]^2 fills the view from z = 4
POINT = ('<emitter type="point"><point name="position" x="0.7" y="0.4" z="1.2"/>'
         '<rgb name="intensity" value="5"/></emitter>')


def scene_xml(shape: str, emitters: str = POINT, res: int = 16, spp: int = 4) -> str:
    return f"""<scene version="3.0.0"><integrator type="path"/>
  <sensor type="perspective"><float name="fov" value="{FOV}"/>
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/><rfilter type="box"/></film></sensor>
  {shape}
  {emitters}
</scene>"""


def render(tmp_path: Path, shape: str, variant: str = "rgb", specialize: bool = True,
           **kw) -> np.ndarray:
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(shape, **kw))
    scene = load_scene(path, variant=variant, specialize=specialize)
    img = scene.render(seed=1)
    assert scene.nonfinite == 0
    return img


def plane(bsdf: str) -> str:
    return f'<shape type="rectangle">{bsdf}</shape>'


def checker(name: str, c0: np.ndarray = C0, c1: np.ndarray = C1) -> str:
    rgb = ", ".join
    return (f'<texture type="checkerboard" name="{name}">'
            f'<rgb name="color0" value="{rgb(map(str, c0))}"/>'
            f'<rgb name="color1" value="{rgb(map(str, c1))}"/></texture>')


def bitmap(tmp_path: Path, name: str, raw: bool = False) -> str:
    """A 2x2 image, C0 on the diagonal and C1 off it, looked up with nearest filtering: the
    checkerboard's layout."""
    write_exr(tmp_path / "alpha.exr", np.array([[C0, C1], [C1, C0]], np.float32))
    return (f'<texture type="bitmap" name="{name}"><string name="filename" '
            f'value="{tmp_path / "alpha.exr"}"/><string name="filter_type" value="nearest"/>'
            + ('<boolean name="raw" value="true"/>' if raw else "") + '</texture>')


def assert_regions(img: np.ndarray, a: np.ndarray, b: np.ndarray, rtol: float = 1e-4) -> None:
    """Each quadrant of ``img`` equals the same quadrant of ``a`` or of ``b``: the diagonal
    quadrants one of them, the others the other (the checkerboard)."""
    h, w = img.shape[0] // 2, img.shape[1] // 2
    assert np.abs(a - b).max() > 0.01 * np.abs(a).max()  # the regions do differ
    quads = [(slice(0, h), slice(0, w)), (slice(h, None), slice(w, None)),
             (slice(0, h), slice(w, None)), (slice(h, None), slice(0, w))]

    def close(x: np.ndarray, y: np.ndarray) -> bool:
        return bool(np.allclose(x, y, rtol=rtol, atol=rtol * np.abs(y).max()))

    on_a = [close(img[q], a[q]) for q in quads]
    on_b = [close(img[q], b[q]) for q in quads]
    assert on_a in ([True, True, False, False], [False, False, True, True]), (on_a, on_b)
    assert on_b == [not x for x in on_a], (on_a, on_b)


def constants(tmp_path: Path, plugin: str, variant: str = "rgb", extra: str = "",
              values: tuple[float, float] = (A0, A1)) -> tuple[np.ndarray, np.ndarray]:
    return tuple(render(tmp_path, plane(f'<bsdf type="{plugin}"><float name="alpha" '
                                        f'value="{a}"/>{extra}</bsdf>'), variant)
                 for a in values)


def test_one_values_are_mitsubas():
    """The constants above are Mitsuba 3's eval_1 of the same textures (the checkerboard's
    regions the other way round, as Mitsuba 3.9's), in its rgb, spectral and mono variants
    (mono: where an LLVM variant runs, DRJIT_LIBLLVM_PATH set)."""
    mi = pytest.importorskip("mitsuba")
    expected = {"scalar_rgb": ((M1, M0), (A0, A1)), "scalar_spectral": ((S1, S0), (A0, A1)),
                "llvm_ad_mono": ((A1, A0), (A0, A1))}
    before, ran = mi.variant(), []
    for variant, (check, bmp) in expected.items():
        try:
            mi.set_variant(variant)
        except (ImportError, RuntimeError, AttributeError):
            assert variant.startswith("llvm")  # the scalar variants always run
            continue
        si = mi.SurfaceInteraction3f()
        tex = mi.load_dict({"type": "checkerboard", "color0": {"type": "rgb", "value": C0},
                            "color1": {"type": "rgb", "value": C1}})
        img = mi.TensorXf(np.array([[C0, C1]], np.float32))
        raw = mi.load_dict({"type": "bitmap", "data": img, "raw": True,
                            "filter_type": "nearest"})
        got, got_bmp = [], []
        for u in (0.25, 0.75):  # color0's region, then color1's (v = 0.25)
            si.uv = mi.Point2f(u, 0.25)
            got.append(float(np.ravel(tex.eval_1(si))[0]))
            got_bmp.append(float(np.ravel(raw.eval_1(si))[0]))
        np.testing.assert_allclose(got, check, rtol=1e-5, err_msg=variant)
        np.testing.assert_allclose(got_bmp, bmp, rtol=1e-5, err_msg=variant)
        ran.append(variant)
    if before:
        mi.set_variant(before)
    assert "scalar_spectral" in ran


def test_roughconductor_alpha_from_checkerboard_and_bitmap(tmp_path):
    for tex, values in ((checker("alpha"), (M0, M1)), (bitmap(tmp_path, "alpha"), (A0, A1))):
        a, b = constants(tmp_path, "roughconductor", values=values)
        img = render(tmp_path, plane(f'<bsdf type="roughconductor">{tex}</bsdf>'))
        assert_regions(img, a, b)


@pytest.mark.parametrize("variant, values", [("mono", (A0, A1)), ("spectral", (S0, S1))])
def test_checkerboard_alpha_in_mono_and_spectral(tmp_path, variant, values):
    """A checkerboard's one value is Mitsuba's per variant: the luminance in mono, the
    upsampled spectrum's mean in spectral."""
    a, b = constants(tmp_path, "roughconductor", variant, values=values)
    img = render(tmp_path, plane(f'<bsdf type="roughconductor">{checker("alpha")}</bsdf>'),
                 variant)
    assert_regions(img, a, b)


def test_constant_texture_equals_constant_alpha(tmp_path):
    a, _ = constants(tmp_path, "roughconductor")
    grey = checker("alpha", np.full(3, A0), np.full(3, A0))
    img = render(tmp_path, plane(f'<bsdf type="roughconductor">{grey}</bsdf>'))
    np.testing.assert_allclose(img, a, rtol=1e-4, atol=1e-6)


def test_textured_alpha_of_roughdielectric(tmp_path):
    a, b = constants(tmp_path, "roughdielectric", values=(M0, M1))
    img = render(tmp_path, plane(f'<bsdf type="roughdielectric">{checker("alpha")}</bsdf>'))
    assert_regions(img, a, b)


def test_roughplastic_alpha_is_a_number(tmp_path):
    """roughplastic precomputes its coating integrals per scene from `alpha` (a table, as
    Mitsuba 3, whose roughplastic takes a float alpha only): a texture there is a clear
    error rather than a silently wrong image."""
    with pytest.raises(CompileError, match="depends on `alpha`, which the scene sets by a "
                                           "texture"):
        render(tmp_path, plane(f'<bsdf type="roughplastic">{checker("alpha")}</bsdf>'))


def test_anisotropic_roughness_from_textures(tmp_path):
    # alpha_u textured, alpha_v constant (and the other way around)
    consts = [render(tmp_path, plane(
        f'<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
        f'<float name="alpha_u" value="{au}"/><float name="alpha_v" value="0.05"/></bsdf>'))
        for au in (M0, M1)]
    img = render(tmp_path, plane(
        '<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
        f'{checker("alpha_u")}<float name="alpha_v" value="0.05"/></bsdf>'))
    assert_regions(img, *consts)


def test_anisotropic_roughness_of_roughdielectric_from_textures(tmp_path):
    # alpha_v textured, alpha_u constant: each region renders as its constant alpha_v
    def bsdf(av: str) -> str:
        return plane(f'<bsdf type="roughdielectric"><float name="alpha_u" value="0.05"/>'
                     f'{av}</bsdf>')
    consts = [render(tmp_path, bsdf(const("alpha_v", av))) for av in (M0, M1)]  # a checkerboard: the mean
    assert_regions(render(tmp_path, bsdf(checker("alpha_v"))), *consts)


def test_textured_alpha_in_spectral_and_generic_builds(tmp_path):
    """In spectral builds a roughness texture's texels stay RGB (its colour lookups would be
    coefficients); the generic build reads the texture's parameters at run time."""
    a, b = constants(tmp_path, "roughconductor", "spectral")
    tex = plane(f'<bsdf type="roughconductor">{bitmap(tmp_path, "alpha", raw=True)}</bsdf>')
    assert_regions(render(tmp_path, tex, "spectral"), a, b)
    # the same texture as a colour and as a roughness: two lookups, two texel encodings
    both = plane(f'<bsdf type="roughconductor">{bitmap(tmp_path, "alpha", raw=True)}'
                 f'{bitmap(tmp_path, "specular_reflectance", raw=True)}</bsdf>')
    assert render(tmp_path, both, "spectral").max() > 0
    generic = render(tmp_path, tex, "rgb", specialize=False)
    np.testing.assert_allclose(generic, render(tmp_path, tex, "rgb"), atol=1e-6)


@pytest.mark.parametrize("bsdf, words", [
    ('<bsdf type="roughconductor"><texture type="checkerboard" name="distribution"/></bsdf>',
     "distribution"),
    ('<bsdf type="dielectric"><texture type="checkerboard" name="int_ior"/></bsdf>',
     "int_ior"),
])
def test_textures_where_they_cannot_go_are_clear_errors(tmp_path, bsdf, words):
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(plane(bsdf)))
    with pytest.raises(CompileError, match=words) as e:
        load_scene(path).compile()
    assert "scene.xml" in str(e.value)


# ---- blend weights and mask opacities from textures ----------------------------------------

GLOSSY = ('<bsdf type="roughconductor"><float name="alpha" value="0.3"/>'
          '<rgb name="specular_reflectance" value="0.9, 0.8, 0.3"/></bsdf>')
MATTE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.4, 0.8"/></bsdf>'


def blend_xml(weight: str) -> str:
    return f'<bsdf type="blendbsdf">{weight}{MATTE}{GLOSSY}</bsdf>'


def mask_xml(opacity: str, inner: str = MATTE) -> str:
    return f'<bsdf type="mask">{opacity}{inner}</bsdf>'


def const(name: str, v: float) -> str:
    return f'<float name="{name}" value="{v!r}"/>'


@pytest.mark.parametrize("make, name", [(blend_xml, "weight"), (mask_xml, "opacity")])
def test_textured_blend_weight_and_mask_opacity(tmp_path, make, name):
    """blendbsdf's weight and mask's opacity read the texture's one-value lookup (`eval_1`,
    as Mitsuba): each checker region renders as the constant weight of that region."""
    for tex, values in ((checker(name), (M0, M1)), (bitmap(tmp_path, name), (A0, A1))):
        a, b = (render(tmp_path, plane(make(const(name, v)))) for v in values)
        assert_regions(render(tmp_path, plane(make(tex))), a, b)


def test_two_textured_weights_in_one_tree_and_the_generic_build(tmp_path):
    """A mask with a textured opacity around a blend with a textured weight (two texture
    slots of one mixture): the regions are the four constant combinations, here along the
    diagonal (both checkerboards share the layout: M0 with M0, M1 with M1).  The generic
    build gives the same image."""
    def tree(opacity: str, weight: str) -> str:
        return plane(mask_xml(opacity, blend_xml(weight)))

    a = render(tmp_path, tree(const("opacity", M0), const("weight", M0)))
    b = render(tmp_path, tree(const("opacity", M1), const("weight", M1)))
    textured = tree(checker("opacity"), checker("weight"))
    assert_regions(render(tmp_path, textured), a, b)
    np.testing.assert_allclose(render(tmp_path, textured, specialize=False),
                               render(tmp_path, textured), atol=1e-6)
    three = plane(mask_xml(checker("opacity"), f'<bsdf type="blendbsdf">{checker("weight")}'
                           f'{MATTE}{blend_xml(checker("weight"))}</bsdf>'))
    path = tmp_path / "three.xml"
    path.write_text(scene_xml(three))
    with pytest.raises(CompileError, match="at most 2 weights or opacities from textures"):
        load_scene(path).compile()


# ---- an area emitter's radiance from a texture ------------------------------------------

L0, L1 = np.array([4.0, 1.0, 0.5]), np.array([0.5, 2.0, 6.0])  # above 1: an EXR holds them


def radiance_bitmap(tmp_path: Path) -> str:
    write_exr(tmp_path / "radiance.exr", np.array([[L0, L1], [L1, L0]], np.float32))
    return ('<texture type="bitmap" name="radiance"><string name="filename" '
            f'value="{tmp_path / "radiance.exr"}"/><string name="filter_type" '
            'value="nearest"/></texture>')


def emitter_plane(radiance: str) -> str:
    return (f'<shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" '
            f'value="0"/></bsdf><emitter type="area">{radiance}</emitter></shape>')


def rgb(name: str, c: np.ndarray) -> str:
    return f'<rgb name="{name}" value="{", ".join(map(str, c))}"/>'


def test_textured_radiance_seen_directly(tmp_path):
    """In rgb a texture's colours are the radiance, as the constant colours are.  (Spectral
    builds upsample a texture's colours as reflectances, clamped to [0, 1] and without D65,
    and a checkerboard's <rgb> above 1 is refused, as in Mitsuba:
    tests/test_spectral_emitter_textures.py.)"""
    a, b = (render(tmp_path, emitter_plane(rgb("radiance", c)), "rgb", emitters="")
            for c in (L0, L1))
    for tex in (checker("radiance", L0 / 6, L1 / 6), radiance_bitmap(tmp_path)):
        scale = 6 if "checkerboard" in tex else 1
        got = render(tmp_path, emitter_plane(tex), "rgb", emitters="")
        assert_regions(got * scale, a, b)


# the receiving point under a pinhole camera, below the emitter (the rectangle [-1, 1]^2
# turned to face down at height 1: its checker colour 0 covers the world quadrants where
# the signs of x and y differ, colour 1 the others)
X0, Y0 = 0.5, 0.3


def _irradiance_corner(a: float, b: float) -> float:
    """Irradiance under a corner of a unit-radiance rectangle [0, a] x [0, b] at height 1."""
    ha, hb = math.hypot(a, 1.0), math.hypot(b, 1.0)
    return 0.5 * (a / ha * math.atan(b / ha) + b / hb * math.atan(a / hb))


def _irradiance(x1: float, x2: float, y1: float, y2: float) -> float:
    """... of the rectangle [x1, x2] x [y1, y2] at height 1 over (X0, Y0), from its corners."""
    def g(x: float, y: float) -> float:
        return math.copysign(1, x) * math.copysign(1, y) * _irradiance_corner(abs(x), abs(y))
    x1, x2, y1, y2 = x1 - X0, x2 - X0, y1 - Y0, y2 - Y0
    return g(x2, y2) - g(x1, y2) - g(x2, y1) + g(x1, y1)


def texel_value(rgb: np.ndarray, variant: str) -> np.ndarray:
    """What the film records, in expectation, for an emitting bitmap's texel ``rgb``: as a
    constant colour in rgb and mono; in spectral the sRGB of its upsampled reflectance
    spectrum (clamped to [0, 1], no D65: Mitsuba's texture_d65 passes a texture through),
    integrated over the sampled wavelengths."""
    from test_envmap_variants import film_value

    if variant != "spectral":
        return film_value(rgb, variant)
    u = (np.arange(1 << 16) + 0.5) / (1 << 16)
    lam, w = S.sample_wavelengths(u)
    spec = S.eval_coeffs(S.rgb_to_coeffs(np.asarray(rgb, np.float64)), lam)
    return S.spectrum_to_srgb(spec, lam, w).mean(axis=0)


@pytest.mark.parametrize("variant", ["mono", "rgb", "spectral"])
def test_textured_radiance_lights_a_plane(tmp_path, variant):
    """Emitter sampling and BSDF sampling both look the radiance up at the uv of the point
    they reach: the plane's brightness is the analytic sum over the checker's regions."""
    light = (f'<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/>'
             f'<translate z="1"/></transform><emitter type="area">'
             f'{radiance_bitmap(tmp_path)}</emitter></shape>')
    floor = ('<shape type="rectangle"><transform name="to_world"><scale value="10"/>'
             '</transform><bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>'
             '</shape>')
    xml = f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective"><float name="fov" value="1"/>
    <transform name="to_world"><lookat origin="{X0},{Y0},0.5" target="{X0},{Y0},0"
      up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="4096"/></sampler>
    <film type="hdrfilm"><integer name="width" value="4"/><integer name="height" value="4"/>
      <rfilter type="box"/></film></sensor>
  {floor}{light}
</scene>"""
    path = tmp_path / "lit.xml"
    path.write_text(xml)
    scene = load_scene(path, variant=variant)
    got = scene.render(seed=2).mean(axis=(0, 1))
    e0 = _irradiance(0, 1, -1, 0) + _irradiance(-1, 0, 0, 1)
    e1 = _irradiance(0, 1, 0, 1) + _irradiance(-1, 0, -1, 0)
    expected = 0.5 / math.pi * (e0 * texel_value(L0, variant) + e1 * texel_value(L1, variant))
    np.testing.assert_allclose(got, expected, rtol=1.5e-2)
