"""Textures on Float parameters (the roughness `alpha`, `alpha_u`, `alpha_v`) and on an area
emitter's `radiance`.

A Float parameter reads the texture's one-value lookup, Mitsuba's `eval_1`: the luminance of
the linear RGB (the value itself for a grey image).  The scene: a unit rectangle filling the
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
from rdsl.runtime.render.image import write_exr
from rdsl.runtime.render.renderer import load_scene

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
C0, C1 = np.array([0.1, 0.6, 0.2]), np.array([0.5, 0.2, 0.9])
A0, A1 = float(C0 @ LUMINANCE), float(C1 @ LUMINANCE)  # 0.4650, 0.3144
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


def constants(tmp_path: Path, plugin: str, variant: str = "rgb", extra: str = ""
              ) -> tuple[np.ndarray, np.ndarray]:
    return tuple(render(tmp_path, plane(f'<bsdf type="{plugin}"><float name="alpha" '
                                        f'value="{a}"/>{extra}</bsdf>'), variant)
                 for a in (A0, A1))


def test_roughconductor_alpha_from_checkerboard_and_bitmap(tmp_path):
    a, b = constants(tmp_path, "roughconductor")
    for tex in (checker("alpha"), bitmap(tmp_path, "alpha")):
        img = render(tmp_path, plane(f'<bsdf type="roughconductor">{tex}</bsdf>'))
        assert_regions(img, a, b)


def test_constant_texture_equals_constant_alpha(tmp_path):
    a, _ = constants(tmp_path, "roughconductor")
    grey = checker("alpha", np.full(3, A0), np.full(3, A0))
    img = render(tmp_path, plane(f'<bsdf type="roughconductor">{grey}</bsdf>'))
    np.testing.assert_allclose(img, a, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("plugin", ["roughdielectric", "roughplastic"])
def test_textured_alpha_of_other_rough_bsdfs(tmp_path, plugin):
    a, b = constants(tmp_path, plugin)
    img = render(tmp_path, plane(f'<bsdf type="{plugin}">{checker("alpha")}</bsdf>'))
    assert_regions(img, a, b)


def test_anisotropic_roughness_from_textures(tmp_path):
    # alpha_u textured, alpha_v constant (and the other way around)
    consts = [render(tmp_path, plane(
        f'<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
        f'<float name="alpha_u" value="{au}"/><float name="alpha_v" value="0.05"/></bsdf>'))
        for au in (A0, A1)]
    img = render(tmp_path, plane(
        '<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
        f'{checker("alpha_u")}<float name="alpha_v" value="0.05"/></bsdf>'))
    assert_regions(img, *consts)


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
