"""Mitsuba 3's `normalmap` and `bumpmap` (stdlib/bsdf/perturbed.rdsl, the perturbed frame in
stdlib/render/integrator.rdsl): a rough plastic plane whose shading normal a normal map or a
bump map tilts, lit by a point light, rendered by rdsl and by Mitsuba 3 (scalar variants), with
Mitsuba's options (flip_invalid_normals, use_shadowing_function, scale) on and off; the
plane without the perturbation is far from both, so the test sees the perturbation.  Bad
input (a texture that is no bitmap, a missing image, a normalmap nested in a combinator, a
missing texture) is an error naming the scene's line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import render_both, scene_header

RES, SPP = 24, 64

pytest.importorskip("PIL")


def _images(folder: Path) -> None:
    from PIL import Image

    y, x = np.mgrid[0:32, 0:32]
    n = np.stack([0.35 * np.sin(x / 3.0), 0.3 * np.cos(y / 4.0), np.ones(x.shape)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    Image.fromarray(((n * 0.5 + 0.5) * 255).round().astype(np.uint8)).save(folder / "nmap.png")
    h = 0.5 + 0.5 * np.sin(x / 2.5) * np.cos(y / 3.5)
    Image.fromarray((h * 255).round().astype(np.uint8)).save(folder / "bump.png")


def _scene(folder: Path, bsdf: str, flip: bool = False) -> Path:
    _images(folder)
    path = folder / "perturbed.xml"
    path.write_text(scene_header("0, -2.5, 3", "0, 0, 0", "0, 0, 1", fov=45, res=RES,
                                 max_depth=4) + f"""  <shape type="rectangle">
    <transform name="to_world"><scale value="1.5"/>{'<rotate x="1" angle="180"/>' * flip}
    </transform>
    {bsdf}
  </shape>
  <emitter type="point"><point name="position" x="1" y="-1" z="2"/>
    <rgb name="intensity" value="8, 8, 8"/></emitter>
</scene>
""")
    return path


NESTED = """<bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0.6, 0.4, 0.2"/>
      <float name="alpha" value="0.2"/></bsdf>"""
NORMALMAP = """<bsdf type="normalmap">{opts}
      <texture name="normalmap" type="bitmap"><string name="filename" value="nmap.png"/>
        <boolean name="raw" value="true"/></texture>
      {nested}
    </bsdf>"""
BUMPMAP = """<bsdf type="bumpmap">{opts}
      <texture name="arbitrary" type="bitmap"><string name="filename" value="bump.png"/>
        <boolean name="raw" value="true"/></texture>
      {nested}
    </bsdf>"""
OFF = """<boolean name="flip_invalid_normals" value="false"/>
      <boolean name="use_shadowing_function" value="false"/>"""

CASES = {
    "normalmap": NORMALMAP.format(opts="", nested=NESTED),
    "normalmap-options-off": NORMALMAP.format(opts=OFF, nested=NESTED),
    "bumpmap": BUMPMAP.format(opts='<float name="scale" value="0.1"/>', nested=NESTED),
    "bumpmap-strong-options-off": BUMPMAP.format(opts='<float name="scale" value="0.4"/>' + OFF,
                                                 nested=NESTED),
    "normalmap-of-twosided": NORMALMAP.format(
        opts="", nested=f'<bsdf type="twosided">{NESTED}</bsdf>'),
    # seen from below (the plane turned over): light from below sees the map mirrored
    "back-of-twosided-normalmap": '<bsdf type="twosided">' + NORMALMAP.format(
        opts="", nested=NESTED) + "</bsdf>",
    "back-of-twosided-bumpmap": '<bsdf type="twosided">' + BUMPMAP.format(
        opts='<float name="scale" value="0.1"/>', nested=NESTED) + "</bsdf>",
}


# every case in rgb; the options are variant-independent, so spectral needs only the two maps
VARIANT_CASES = [(c, "rgb") for c in sorted(CASES)] + [(c, "spectral")
                                                        for c in ("bumpmap", "normalmap")]


@pytest.mark.parametrize(("case", "variant"), VARIANT_CASES)
def test_perturbed_frame_matches_mitsuba(tmp_path: Path, case: str, variant: str):
    back = case.startswith("back")
    img, ref = render_both(_scene(tmp_path, CASES[case], back), variant, SPP)
    flat_dir = tmp_path / "flat"
    flat_dir.mkdir()
    flat, flat_ref = render_both(_scene(flat_dir, f'<bsdf type="twosided">{NESTED}</bsdf>',
                                        back), variant, SPP)

    def rmse(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a - b) ** 2)))

    # what the perturbation changes, against how far rdsl is from Mitsuba (both noisy: the
    # flat plane's rdsl-vs-Mitsuba distance is the noise floor)
    effect, err, floor = rmse(ref, flat_ref), rmse(img, ref), rmse(flat, flat_ref)
    assert effect > 0.01, effect
    assert err < max(2.0 * floor, 0.1 * effect), (err, floor, effect)
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.02)


BAD = {
    "checkerboard": (BUMPMAP.replace('<texture name="arbitrary" type="bitmap"><string name="'
                                     'filename" value="bump.png"/>\n        <boolean name="raw" '
                                     'value="true"/></texture>',
                                     '<texture name="h" type="checkerboard"/>'),
                     'type="checkerboard"', "`texture` must be a bitmap texture (the renderer reads its gradient), "
                     "got a `checkerboard` texture"),
    "missing-image": (NORMALMAP.replace("nmap.png", "nope.png"), 'nope.png',
                      "texture file 'nope.png' not found"),
    "constant": (NORMALMAP.replace('<texture name="normalmap" type="bitmap"><string name="'
                                   'filename" value="nmap.png"/>\n        <boolean name="raw" '
                                   'value="true"/></texture>',
                                   '<rgb name="normalmap" value="0.5, 0.5, 1"/>'),
                 'type="normalmap"',
                 "`normalmap` must be a bitmap texture (the renderer reads its RGB normals), "
                 "got a constant"),
    "no-texture": (NORMALMAP.replace('<texture name="normalmap" type="bitmap"><string name="'
                                     'filename" value="nmap.png"/>\n        <boolean name="raw" '
                                     'value="true"/></texture>', ""), 'type="normalmap"',
                   "bsdf 'normalmap' is missing the required parameter 'normalmap'"),
    "scale-rgb": (BUMPMAP.replace("{opts}", '<rgb name="scale" value="0.1, 0.2, 0.3"/>'),
                  '<rgb name="scale"',
                  "parameter 'scale' of bsdf 'bumpmap' expects a float, got <rgb>"),
    "nested": ('<bsdf type="blendbsdf"><float name="weight" value="0.5"/>' + NORMALMAP + NESTED
               + "</bsdf>", 'type="normalmap"',
               "a normalmap nested in a combinator (twosided, blendbsdf, mask) is not supported"),
    "two-bsdfs": (NORMALMAP.replace("{nested}", "{nested}{nested}"),
                  "<bsdf type=\"roughplastic\"",
                  "bsdf 'normalmap' takes 1 nested <bsdf>, got 2"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_an_error_at_its_line(tmp_path: Path, case: str):
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.renderer import load_scene

    body, marker, message = BAD[case]
    path = _scene(tmp_path, body.format(opts="", nested=NESTED) if "{" in body else body)
    lines = path.read_text().splitlines()
    line = next(i for i, ln in enumerate(lines, 1) if marker in ln)
    if case == "two-bsdfs":  # the second nested BSDF
        line = next(i for i, ln in enumerate(lines, 1) if marker in ln and i > line)
    with pytest.raises(CompileError) as e:
        load_scene(path).render(spp=1)
    text = str(e.value)
    assert message in text, text
    assert f"{path}:{line}:" in text, (line, text)


def test_generic_build_gives_the_same_image(tmp_path: Path):
    """`--no-specialize`: the perturbed plugin's parameters (its texture's id included) read
    from the parameter buffer at run time give the specialized kernel's image bit for bit."""
    from rdsl.runtime.render.renderer import load_scene

    path = _scene(tmp_path, '<bsdf type="twosided">' + BUMPMAP.format(
        opts='<float name="scale" value="0.2"/>', nested=NESTED) + "</bsdf>")
    a = load_scene(path).render(spp=4, seed=0)
    b = load_scene(path, specialize=False).render(spp=4, seed=0)
    np.testing.assert_array_equal(a, b)
