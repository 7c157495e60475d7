"""`hide_emitters` against Mitsuba 3.9 (scalar_rgb): camera rays pass through area emitters
(Mitsuba's SamplingIntegrator::skip_area_emitters), so the wall behind a hidden light shows
and the alpha is 0 where nothing is behind it; the light still lights the scene (emitter
sampling) and is seen through a mirror (depth > 0).  Colour and alpha (rgba film),
noise-aware, for `path` and `direct`, with hide_emitters true and false."""

from __future__ import annotations

import pytest
from test_film_alpha import assert_alpha_matches, assert_colour_matches, colour, render_both

pytest.importorskip("rdsl.runtime.embree")

# a diffuse wall on the left half; in front of it a two-sided-looking pair of area lights
# (one facing the camera, one the wall) half over the wall and half over the void; a
# mirror on the right that reflects the one facing the wall; a point light
SCENE = """<scene version="3.0.0">
  {integrator}
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
    <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="16"/>
      <string name="pixel_format" value="rgba"/></film>
  </sensor>
  <shape type="rectangle"><transform name="to_world"><scale x="1" y="2"/>
    <translate x="-1" z="-1"/></transform><bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="0.5" y="0.3"/>
    <translate x="-0.2" y="0.2" z="0.5"/></transform>
    <emitter type="area"><rgb name="radiance" value="4,2,1"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale x="0.5" y="0.3"/>
    <rotate y="1" angle="180"/><translate x="-0.2" y="-0.4" z="0.5"/></transform>
    <emitter type="area"><rgb name="radiance" value="3"/></emitter></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.4"/>
    <rotate y="1" angle="-43"/><translate x="1.3" y="-0.2"/></transform>
    <bsdf type="conductor"/></shape>
  <emitter type="point"><point name="position" value="0,2,3"/>
    <rgb name="intensity" value="3"/></emitter>
</scene>"""


@pytest.mark.parametrize("integrator", ["path", "direct"])
@pytest.mark.parametrize("hide", ["true", "false"])
def test_hidden_area_emitters_are_mitsubas(tmp_path, integrator, hide):
    """Colour and alpha of an rgba film against Mitsuba's, with the lights in view."""
    xml = SCENE.format(integrator=f'<integrator type="{integrator}"><boolean '
                                  f'name="hide_emitters" value="{hide}"/></integrator>')
    ours, theirs = render_both(tmp_path, xml)
    assert sorted(ours) == sorted(theirs) == ["A", "B", "G", "R"]
    what = f"{integrator}.hide_emitters={hide}"
    assert_alpha_matches(ours["A"], theirs["A"], 64, 512, what)
    assert_colour_matches(colour(ours, "RGB"), colour(theirs, "RGB"), what)
    # the case tests what it claims: the lights are in view unless hidden (left half), and
    # the mirror shows them either way (right half)
    lit = theirs["R"] > 1.5
    assert (hide == "false") == bool(lit[:, :14].any()), what
    assert lit[:, 14:].any(), what
