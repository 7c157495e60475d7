"""Textured emitted light as Mitsuba 3 renders it, in rgb and spectral: an area light whose
`radiance` is a texture, seen directly, against the same scene rendered by Mitsuba 3.

Mitsuba's emitters read their colour with ``Properties::texture_d65``: a constant `<rgb>`
becomes a D65 illuminant spectrum (the colour itself, seen directly), but a texture is
passed through as it is.  A checkerboard's `<rgb>` colours and a bitmap's texels are then
upsampled as reflectances are (``srgb_model_fetch``, which clamps each component to
[0, 1]), with no D65: seen directly, the spectrum of (0.9, 0.1, 0.1) under the
equal-energy illuminant reads about (1.04, 0.09, 0.09) in spectral builds, and an EXR
texel (2.7, 0.3, 0.3) reads as (1, 0.3, 0.3) does.  Mitsuba's checkerboard also refuses an
`<rgb>` colour above 1 (a bounded ``srgb`` reflectance).  The rgb variants see none of this.

Each pixel here sees the light alone, so a pixel's value is the radiance (exact in rgb; in
spectral, up to the noise of the sampled wavelengths, well below the tolerance).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from _mitsuba_render import mitsuba_variant
from rdsl.runtime.render.image import write_exr
from rdsl.runtime.render.renderer import load_scene
from test_nested_textures import scene_xml as nested_scene_xml

RED = (0.9, 0.1, 0.1)


def rgb(name: str, c: tuple[float, ...]) -> str:
    return f'<rgb name="{name}" value="{", ".join(map(str, c))}"/>'


def checker(name: str, c0: str, c1: str) -> str:
    return f'<texture type="checkerboard" name="{name}">{c0}{c1}</texture>'


def bitmap(name: str, path: Path) -> str:
    return (f'<texture type="bitmap" name="{name}"><string name="filename" '
            f'value="{path}"/></texture>')


def images(tmp_path: Path) -> dict[str, Path]:
    """4x4 images of one colour: an 8-bit sRGB PNG of RED, EXRs of RED and 3 RED."""
    image = pytest.importorskip("PIL.Image")
    red = np.broadcast_to(np.float32(RED), (4, 4, 3))
    write_exr(tmp_path / "red.exr", red)
    write_exr(tmp_path / "red3.exr", 3 * red)
    lin = np.asarray(RED)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    png = np.broadcast_to(np.round(255 * srgb).astype(np.uint8), (4, 4, 3))
    image.fromarray(np.ascontiguousarray(png)).save(tmp_path / "red.png")
    return {"png": tmp_path / "red.png", "exr": tmp_path / "red.exr",
            "exr3": tmp_path / "red3.exr"}


def radiance(case: str, files: dict[str, Path]) -> str:
    """The `radiance` of each case: a constant, a checkerboard of constants, bitmaps, and a
    bitmap nested in a checkerboard."""
    red = rgb("?", RED)
    if case == "constant":
        return rgb("radiance", RED)
    if case == "checkerboard":
        return checker("radiance", red.replace("?", "color0"), red.replace("?", "color1"))
    if case == "nested":
        return checker("radiance", bitmap("color0", files["exr"]), red.replace("?", "color1"))
    return bitmap("radiance", files[case])


def scene_xml(radiance: str, spp: int) -> str:
    """The unit rectangle filling the view (tests/test_nested_textures.py), an area light."""
    return nested_scene_xml(f'<emitter type="area">{radiance}</emitter>', "", spp)


def means(path: Path, variant: str, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """(rdsl's, Mitsuba's) mean pixel colour of the scene file ``path``."""
    with mitsuba_variant(f"scalar_{variant}") as mi:
        theirs = np.array(mi.render(mi.load_file(str(path)), spp=spp, seed=1))[..., :3]
    ours = np.asarray(load_scene(path, variant=variant).render(spp=spp, seed=2))[..., :3]
    return ours.reshape(-1, 3).mean(axis=0), theirs.reshape(-1, 3).mean(axis=0)


CASES = ["constant", "checkerboard", "png", "exr", "exr3", "nested"]


@pytest.mark.parametrize("variant", ["rgb", "spectral"])
@pytest.mark.parametrize("case", CASES)
def test_textured_radiance_seen_directly_is_mitsubas(tmp_path, case, variant):
    path = tmp_path / "scene.xml"
    spp = 4 if variant == "rgb" else 32
    path.write_text(scene_xml(radiance(case, images(tmp_path)), spp))
    ours, theirs = means(path, variant, spp)
    # spectral: 16 x 16 x 32 samples of the wavelengths, a relative noise well under 1%, while
    # D65 on a textured light (rdsl's old values) moves red by 15% and green by 10%
    tol = 1e-4 if variant == "rgb" else 0.025
    assert np.all(np.abs(ours - theirs) <= tol * theirs), (case, variant, ours, theirs)


def test_spectral_texture_is_not_times_d65(tmp_path):
    """The point of the file, stated against Mitsuba: in spectral, a checkerboard of RED
    seen directly is redder than the constant RED (Mitsuba's 1.04 against 0.90)."""
    files = images(tmp_path)
    red = []
    for case in ("constant", "checkerboard"):
        path = tmp_path / f"{case}.xml"
        path.write_text(scene_xml(radiance(case, files), 32))
        red.append([m[0] for m in means(path, "spectral", 32)])
    (ours_c, theirs_c), (ours_t, theirs_t) = red
    assert theirs_t > 1.1 * theirs_c and ours_t > 1.1 * ours_c, red


@pytest.mark.parametrize("value", ["2.7, 0.3, 0.3", "1.0001, 0.5, 0.5"])
def test_checkerboard_rgb_above_one_is_refused_at_its_line(tmp_path, value):
    """Mitsuba refuses it (``SRGBReflectanceSpectrum``: "Invalid RGB reflectance value");
    rdsl too, with the file and line of the `<rgb>`."""
    from rdsl.runtime.scene import SceneError

    emitter = checker("radiance", f'\n<rgb name="color0" value="{value}"/>',
                      rgb("color1", RED))
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(emitter, 1))
    with mitsuba_variant("scalar_rgb") as mi, pytest.raises(Exception, match="Invalid RGB"):
        mi.load_file(str(path))
    with pytest.raises(SceneError) as e:
        load_scene(path)
    line = next(i + 1 for i, text in enumerate(path.read_text().splitlines())
                if text.startswith(f'<rgb name="color0" value="{value}"/>'))
    assert f"scene.xml:{line}:" in str(e.value) and "in [0, 1]" in str(e.value)


def test_checkerboard_float_above_one_is_accepted(tmp_path):
    """A `<float>` colour is a flat spectrum, not a bounded reflectance: Mitsuba takes it."""
    emitter = checker("radiance", '<float name="color0" value="2"/>',
                      '<float name="color1" value="2"/>')
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(emitter, 4))
    ours, theirs = means(path, "rgb", 4)
    assert np.allclose(ours, theirs, rtol=1e-4) and np.allclose(theirs, 2.0, rtol=1e-4)
