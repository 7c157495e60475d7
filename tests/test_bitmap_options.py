"""Mitsuba 3's `bitmap` options in a scene, rendered by rdsl and by Mitsuba 3 (scalar_rgb,
scalar_spectral): six planes, one per `filter_type` (bilinear, nearest) and `wrap_mode`
(repeat, mirror, clamp), each with a small sRGB PNG as its diffuse reflectance under a
`to_uv` that tiles it 2.5 times (so every wrap mode shows), with `raw` on and off; a plane's
mean and its blocks must match Mitsuba's.  The lookups themselves are checked against
Mitsuba's texture (eval_3) in tests/test_perturbed_frame.py and against a transcription of
Dr.Jit's in tests/test_textures.py; bad option values are errors at their line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import block_error, render_both, scene_header

pytest.importorskip("PIL")
RES, SPP = 48, 64
COMBOS = [(f, w) for f in ("bilinear", "nearest") for w in ("repeat", "mirror", "clamp")]


def _scene(folder: Path, raw: bool, option: str = "") -> Path:
    from PIL import Image

    px = np.random.default_rng(4).integers(20, 255, (5, 4, 3)).astype(np.uint8)
    Image.fromarray(px, "RGB").save(folder / "tex.png")
    planes = ""
    for k, (filt, wrap) in enumerate(COMBOS):
        x, y = -1.1 + 1.1 * (k % 3), 0.55 - 1.1 * (k // 3)
        planes += f"""  <shape type="rectangle">
    <transform name="to_world"><scale value="0.5"/><translate x="{x}" y="{y}"/></transform>
    <bsdf type="diffuse"><texture type="bitmap" name="reflectance">
      <string name="filename" value="tex.png"/><boolean name="raw" value="{str(raw).lower()}"/>
      <string name="filter_type" value="{filt}"/><string name="wrap_mode" value="{wrap}"/>
      <transform name="to_uv"><scale x="2.5" y="2.5"/><translate x="-0.7" y="-0.6"/>
      </transform>{option}
    </texture></bsdf>
  </shape>
"""
    path = folder / "bitmaps.xml"
    path.write_text(scene_header("0, 0, 4", "0, 0, 0", "0, 1, 0", fov=40, res=RES, max_depth=2)
                    + planes + """  <emitter type="point"><point name="position" x="0" y="0" z="3"/>
    <rgb name="intensity" value="10, 10, 10"/></emitter>
</scene>
""")
    return path


# no raw+spectral: Mitsuba refuses a raw bitmap as a spectrum (rdsl upsamples its values)
@pytest.mark.parametrize(("raw", "variant"), [(False, "rgb"), (True, "rgb"),
                                              (False, "spectral")],
                         ids=["srgb-rgb", "raw-rgb", "srgb-spectral"])
def test_bitmap_options_match_mitsuba(tmp_path: Path, raw: bool, variant: str):
    img, ref = render_both(_scene(tmp_path, raw), variant, SPP)
    assert ref.mean() > 0.05
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.02)
    err = block_error(img, ref, b=4)  # 0.046 (rgb), 0.085 (spectral: colour noise) at 64 spp
    assert err < 0.12, err


@pytest.mark.parametrize("option,message", [
    ('<string name="wrap_mode" value="wrap"/>', "wrap_mode"),
    ('<string name="filter_type" value="cubic"/>', "filter_type"),
    ('<integer name="raw" value="1"/>', "raw"),
])
def test_bad_options_are_errors_at_their_line(tmp_path: Path, option: str, message: str):
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.renderer import load_scene

    path = _scene(tmp_path, False, option)
    line = 1 + next(i for i, s in enumerate(path.read_text().splitlines()) if option in s)
    with pytest.raises(CompileError) as e:
        load_scene(path)
    assert f"{path}:{line}:" in str(e.value) and message in str(e.value), str(e.value)
