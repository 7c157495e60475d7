"""Mitsuba 3's spectrum plugins, ``<spectrum type="uniform|d65|blackbody|regular|irregular|
srgb" name="...">`` with nested properties (runtime/scene/spectrum_plugins.py), against
Mitsuba 3 itself: each sets both the radiance of an area light the camera sees directly and
the reflectance of a sphere under a uniform white environment, so the image holds the
spectrum's emitted colour and its reflected colour, both noise-free in their centres.  The
rgb variant against Mitsuba's rgb for the plugins its rgb variants take (uniform, d65, srgb);
for the others (which Mitsuba's rgb variants refuse) rdsl's rgb light against Mitsuba's
spectral one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import render_both, scene_header

PLUGINS = {
    "uniform": '<float name="value" value="0.35"/>',
    "d65": '<float name="scale" value="0.6"/>',
    "srgb": '<rgb name="color" value="0.7, 0.2, 0.45"/>',
    "regular": ('<float name="wavelength_min" value="420"/>'
                '<float name="wavelength_max" value="680"/>'
                '<string name="values" value="0.9, 0.1, 0.5, 0.3, 0.8"/>'),
    "irregular": ('<string name="wavelengths" value="380, 470, 520, 610, 800"/>'
                  '<string name="values" value="0.2, 0.9, 0.3, 0.6, 0.1"/>'),
    "blackbody": '<float name="temperature" value="3200"/>',
}
RGB_OK = ("uniform", "d65", "srgb")


def scene(plugin: str) -> str:
    body = PLUGINS[plugin]
    spec = f'<spectrum type="{plugin}" name="{{}}">{body}</spectrum>'
    return scene_header("0, 0, 4", "0, 0, 0", "0, 1, 0", fov=40, res=16, max_depth=2) + f"""
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
  <shape type="sphere"><float name="radius" value="0.6"/><point name="center" x="-0.7" y="0" z="0"/>
    <bsdf type="diffuse">{spec.format("reflectance") if plugin != "blackbody" else ""}</bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.6"/><translate x="0.7"/></transform>
    <emitter type="area">{spec.format("radiance")}</emitter>
  </shape>
</scene>
"""


CASES = [(p, "spectral") for p in PLUGINS] + [(p, "rgb") for p in RGB_OK]


@pytest.mark.parametrize("plugin,variant", CASES, ids=[f"{p}-{v}" for p, v in CASES])
def test_spectrum_plugin_matches_mitsuba(plugin: str, variant: str, tmp_path: Path) -> None:
    path = tmp_path / "s.xml"
    path.write_text(scene(plugin))
    ours, theirs = render_both(path, variant, spp=64)
    light = (slice(6, 10), slice(10, 13))
    sphere = (slice(6, 10), slice(3, 6))
    for region in (light, sphere):
        a, b = ours[region].mean(axis=(0, 1)), theirs[region].mean(axis=(0, 1))
        np.testing.assert_allclose(a, b, rtol=0.03, atol=0.01 * max(1.0, float(b.max())))
    # the spectrum is coloured where it should be: not a grey stand-in
    if plugin in ("srgb", "regular", "irregular", "blackbody"):
        b = theirs[light].mean(axis=(0, 1))
        assert b.max() - b.min() > 0.05 * b.max()


@pytest.mark.parametrize("plugin", [p for p in PLUGINS if p not in RGB_OK])
def test_rgb_takes_the_srgb_projection(plugin: str, tmp_path: Path) -> None:
    """Mitsuba's rgb variants refuse these plugins (checked); rdsl's rgb variant takes the
    spectrum's sRGB projection, so the light the camera sees is the colour Mitsuba's
    spectral variant develops for it."""
    from _mitsuba_render import mitsuba_variant
    from rdsl.runtime.render.renderer import load_scene

    pytest.importorskip("rdsl.runtime.embree")
    path = tmp_path / "s.xml"
    path.write_text(scene(plugin))
    with mitsuba_variant("scalar_rgb") as mi:
        with pytest.raises(Exception, match="[Nn]ot implemented"):  # when it renders
            mi.render(mi.load_file(str(path)), spp=1)
    with mitsuba_variant("scalar_spectral") as mi:
        theirs = np.array(mi.render(mi.load_file(str(path)), spp=64, seed=1))[..., :3]
    ours = np.asarray(load_scene(path, variant="rgb").render(spp=64, seed=2))[..., :3]
    light = (slice(6, 10), slice(10, 13))
    a, b = ours[light].mean(axis=(0, 1)), theirs[light].mean(axis=(0, 1))
    np.testing.assert_allclose(a, b, rtol=0.03, atol=0.01 * max(1.0, float(b.max())))


def test_spectrum_plugin_errors(tmp_path: Path) -> None:
    import rdsl
    from rdsl.compiler.diagnostics import CompileError
    cases = {
        '<spectrum type="planck" name="radiance"/>': "unknown spectrum plugin 'planck'",
        '<spectrum type="blackbody" name="radiance"/>': "needs the parameter 'temperature'",
        '<spectrum type="blackbody" name="radiance"><float name="temp" value="1"/>'
        '</spectrum>': "has no parameter 'temp'",
        '<spectrum type="irregular" name="radiance"><string name="wavelengths" value="400,'
        ' 500"/><string name="values" value="1"/></spectrum>': "2 wavelengths but 1 values",
        '<spectrum type="uniform" name="radiance" value="2"/>': "unexpected attribute 'value'",
    }
    for spec, message in cases.items():
        path = tmp_path / "bad.xml"
        path.write_text(scene_header("0, 0, 4", "0, 0, 0", "0, 1, 0") + f"""
  <shape type="sphere"><emitter type="area">{spec}</emitter></shape></scene>""")
        with pytest.raises(CompileError) as e:
            rdsl.load_scene(path).render(spp=1)
        assert message in str(e.value) and "bad.xml:" in str(e.value), str(e.value)


def test_load_dict_takes_spectrum_plugins(tmp_path: Path) -> None:
    """``{"type": "blackbody", ...}`` and the others in Mitsuba's dict form give the image of
    the same scene written in XML."""
    pytest.importorskip("rdsl.runtime.embree")
    import rdsl
    cam = {"type": "perspective", "fov": 40.0,
           "to_world": rdsl.Transform4f().look_at([0, 0, 4], [0, 0, 0], [0, 1, 0]),
           "film": {"type": "hdrfilm", "width": 16, "height": 16}}
    d = {"type": "scene", "integrator": {"type": "path", "max_depth": 2}, "sensor": cam,
         "env": {"type": "constant", "radiance": {"type": "srgb", "color": [0.2, 0.5, 0.9]}},
         "ball": {"type": "sphere", "radius": 0.6, "center": [-0.7, 0.0, 0.0],
                  "bsdf": {"type": "diffuse", "reflectance": {
                      "type": "irregular", "wavelengths": [380, 520, 800],
                      "values": "0.2, 0.9, 0.3"}}},
         "lamp": {"type": "rectangle",
                  "to_world": rdsl.Transform4f().translate([0.7, 0, 0]).scale(0.6),
                  "emitter": {"type": "area", "radiance": {"type": "blackbody",
                                                           "temperature": 3200.0}}}}
    xml = scene_header("0, 0, 4", "0, 0, 0", "0, 1, 0", fov=40, res=16, max_depth=2) + """
  <emitter type="constant"><spectrum type="srgb" name="radiance">
    <rgb name="color" value="0.2, 0.5, 0.9"/></spectrum></emitter>
  <shape type="sphere"><float name="radius" value="0.6"/>
    <point name="center" x="-0.7" y="0" z="0"/>
    <bsdf type="diffuse"><spectrum type="irregular" name="reflectance">
      <string name="wavelengths" value="380, 520, 800"/>
      <string name="values" value="0.2, 0.9, 0.3"/></spectrum></bsdf></shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="0.6"/><translate x="0.7"/></transform>
    <emitter type="area"><spectrum type="blackbody" name="radiance">
      <float name="temperature" value="3200"/></spectrum></emitter></shape>
</scene>"""
    path = tmp_path / "s.xml"
    path.write_text(xml)
    ours = rdsl.load_dict(d, variant="spectral").render(spp=4, seed=1)
    ref = rdsl.load_scene(path, variant="spectral").render(spp=4, seed=1)
    assert float(np.abs(ref).max()) > 0
    np.testing.assert_array_equal(ours, ref)
