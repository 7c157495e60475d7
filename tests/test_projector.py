"""Mitsuba 3's `projector` emitter (stdlib/emitter/projector.rdsl): a constant and a textured
projector lighting a wall and a sphere, rendered by rdsl and by Mitsuba 3 (scalar_rgb, and
scalar_spectral) and compared the noise-aware way; and its bad inputs, each a clear error
naming the line."""

from __future__ import annotations

import numpy as np
import pytest
from _plugin_scenes import check_bad, median_rmse, perspective, write_scene, write_slide

pytest.importorskip("rdsl.runtime.embree")
pytest.importorskip("mitsuba")

IRRADIANCE = {
    "constant": '<rgb name="irradiance" value="0.8, 0.5, 0.3"/>',
    "default": "",
    # a 24 x 12 slide (aspect 2): its fov is given along y, and the image is not symmetric
    "bitmap": ('<texture type="bitmap" name="irradiance"><string name="filename" '
               'value="{png}"/></texture><string name="fov_axis" value="y"/>'),
    "checkerboard": ('<texture type="checkerboard" name="irradiance"><rgb name="color0" '
                     'value="1, 0.2, 0.1"/><rgb name="color1" value="0.1, 0.4, 1"/>'
                     '<transform name="to_uv"><scale x="4" y="3"/></transform></texture>'),
}


def _scene(tmp_path, irradiance: str, fov: str = '<float name="fov" value="35"/>'):
    png = write_slide(tmp_path / "slide.png", 12, 24, background=40)
    irr = IRRADIANCE[irradiance].format(png=png)
    body = f"""<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.8, 0.8"/></bsdf></shape>
  <shape type="sphere"><float name="radius" value="0.3"/>
    <point name="center" x="0.5" y="-0.3" z="0.5"/><bsdf type="diffuse"/></shape>
  <emitter type="projector">{irr}<float name="scale" value="6"/>{fov}
    <transform name="to_world"><lookat origin="0.7, 0.4, 3" target="0, 0, 0" up="0, 1, 0"/>
    </transform></emitter>"""
    return write_scene(tmp_path, body, perspective(fov=50), max_depth=3, room=False)


@pytest.mark.parametrize("irradiance", sorted(IRRADIANCE))
def test_projector_against_mitsuba(tmp_path, irradiance):
    mine, theirs = median_rmse(_scene(tmp_path, irradiance), 16, ref_spp=1024)
    assert mine <= 1.2 * theirs, (mine, theirs)


@pytest.mark.parametrize("irradiance", ["constant", "bitmap"])
def test_projector_spectral_against_mitsuba(tmp_path, irradiance):
    # Mitsuba's default field of view (a 50mm focal length) on the bitmap (fov_axis y)
    fov = '<float name="fov" value="20"/>' if irradiance == "bitmap" else ""
    mine, theirs = median_rmse(_scene(tmp_path, irradiance, fov), 16, ref_spp=1024,
                               variant="spectral")
    assert mine <= 1.2 * theirs, (mine, theirs)


def test_constant_projection_onto_a_facing_plane_is_constant(tmp_path):
    """Mitsuba's normalisation, analytically: a plane facing the projector at distance z
    receives irradiance E = irradiance pi scale / z^2 across the whole projected image (the
    1/dist^2 and the cosines cancel), so a diffuse plane of albedo a shows a E / pi inside
    the image's rectangle, |x|, |y| < z tan(fov / 2), and nothing outside."""
    z, fov, irradiance, scale, albedo = 3.0, 70.0, 0.5, 2.0, 0.8
    body = f"""<shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
    <bsdf type="diffuse"><float name="reflectance" value="{albedo}"/></bsdf></shape>
  <emitter type="projector"><float name="irradiance" value="{irradiance}"/>
    <float name="scale" value="{scale}"/><float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="0, 0, {z}" target="0, 0, 0" up="0, 1, 0"/>
    </transform></emitter>"""
    sensor = ('<sensor type="orthographic"><transform name="to_world"><scale value="2.5"/>'
              '<lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>'
              '<film type="hdrfilm"><integer name="width" value="50"/>'
              '<integer name="height" value="50"/><rfilter type="box"/></film></sensor>')
    import rdsl

    img = rdsl.load_scene(write_scene(tmp_path, body, sensor, max_depth=2, room=False)
                          ).render(spp=4, seed=0)[..., :3]
    centres = np.abs(-2.5 + 0.1 * (np.arange(50) + 0.5))  # |x| (and |y|) of pixel centres
    half = z * np.tan(np.radians(fov / 2))
    inside = (centres < half - 0.1)[:, None] & (centres < half - 0.1)[None, :]
    outside = (centres > half + 0.1)[:, None] | (centres > half + 0.1)[None, :]
    expected = albedo * irradiance * scale / z**2
    np.testing.assert_allclose(img[inside], expected, rtol=2e-4)
    assert np.all(img[outside] == 0.0)


BAD = {
    "scale_type": ('<string name="scale" value="x"/>', "parameter 'scale' of emitter "
                   "'projector' expects a float, got <string>"),
    "scale_negative": ('<float name="scale" value="-1"/>', "'scale' must be >= 0"),
    "fov_range": ('<float name="fov" value="190"/>',
                  "'fov' must be between 0 and 180 degrees, got 190"),
    "fov_and_focal_length": ('<float name="fov" value="30"/><string name="focal_length" '
                             'value="50mm"/>', "give either 'fov' or 'focal_length'"),
    "focal_length": ('<string name="focal_length" value="abc"/>', "cannot parse focal_length"),
    "fov_axis_value": ('<float name="fov" value="30"/><string name="fov_axis" value="z"/>',
                       "'fov_axis' of emitter 'projector' is 'z'; accepted: x, y"),
    "fov_axis_without_fov": ('<string name="fov_axis" value="y"/>',
                             "'fov_axis' applies to 'fov' only"),
    "irradiance_type": ('<boolean name="irradiance" value="true"/>',
                        "'irradiance' of emitter 'projector' expects a color"),
    "unknown": ('<float name="cutoff_angle" value="3"/>',
                "unknown parameter 'cutoff_angle' of emitter 'projector'"),
    "missing_texture": ('<texture type="bitmap" name="irradiance"><string name="filename" '
                        'value="nope.png"/></texture>', "texture file 'nope.png' not found"),
    "corrupt_texture": ('<texture type="bitmap" name="irradiance"><string name="filename" '
                        'value="{bad}"/></texture>', "cannot load"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_projector_input_names_the_line(tmp_path, case):
    xml, message = BAD[case]
    (tmp_path / "bad.png").write_bytes(b"not an image")
    check_bad(tmp_path, f'<emitter type="projector">{xml.format(bad=tmp_path / "bad.png")}'
              "</emitter>", message)


def test_singular_to_world_names_the_emitter(tmp_path):
    import rdsl

    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n  <shape type="sphere"/>\n  <emitter '
                    'type="projector"><transform name="to_world"><scale value="0"/>'
                    "</transform></emitter>\n</scene>\n")
    with pytest.raises(Exception) as exc:
        rdsl.load_scene(path).render(spp=1)
    assert str(exc.value).startswith(f"{path}:3:") and "'to_world' is singular" in str(exc.value)
