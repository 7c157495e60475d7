"""The `null` BSDF (stdlib/bsdf/null.rdsl, Mitsuba 3's null.cpp): light passes straight
through it.  A small scene rendered by rdsl and by Mitsuba 3 (scalar_rgb, scalar_spectral):
an area light whose shape has a null BSDF (the camera sees its back, which does not emit, and
looks through it at the floor it lights), a null occluder between the floor and the light
(it blocks shadow rays, as in Mitsuba's `path`, while BSDF-sampled rays pass through it) and
a `blendbsdf` of a diffuse BSDF and a null one (half transparent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import block_error, render_both, scene_header

RES, SPP = 24, 1024
SCENE = scene_header("0, -1.5, 4", "0, 0, 0", "0, 1, 0", fov=50, res=RES, max_depth=6) + """
  <shape type="rectangle">
    <transform name="to_world"><scale value="2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.3"/></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.6"/><translate z="1.6"/></transform>
    <boolean name="flip_normals" value="true"/>
    <bsdf type="null"/>
    <emitter type="area"><rgb name="radiance" value="6, 5, 4"/></emitter>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.4"/><translate x="0.7" z="0.8"/></transform>
    <bsdf type="null"/>
  </shape>
  <shape type="sphere">
    <float name="radius" value="0.35"/><point name="center" x="-0.8" y="0.3" z="0.4"/>
    <bsdf type="blendbsdf"><float name="weight" value="0.5"/>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf>
      <bsdf type="null"/>
    </bsdf>
  </shape>
</scene>
"""


@pytest.mark.parametrize("variant", ["rgb", "spectral"])
def test_null_scene_matches_mitsuba(tmp_path: Path, variant: str):
    path = tmp_path / "null.xml"
    path.write_text(SCENE)
    img, ref = render_both(path, variant, SPP)
    # the light's back is black, the floor seen through the light and the occluder is lit
    assert ref.mean() > 0.05
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.02)
    err = block_error(img, ref)
    assert err < 0.06, err


@pytest.mark.parametrize("variant", ["mono", "spectral", "mono_polarized", "spectral_polarized"])
def test_null_passes_the_test_kit(capsys, variant: str):
    """`rdsl test-plugin stdlib/bsdf/null.rdsl` in the variants test_testkit.py leaves out:
    one Dirac lobe of probability 1 along -wi, albedo 1, finite values."""
    from rdsl.cli import main

    rc = main(["test-plugin", str(Path(__file__).resolve().parents[1] / "stdlib" / "bsdf"
                                  / "null.rdsl"), "--variant", variant, "--samples", "20000"])
    out = capsys.readouterr().out
    assert rc == 0 and " FAIL" not in out and "chi2 sample vs pdf" in out, out
    assert "albedo = 1.0000" in out, out
