"""Mitsuba 3 scene loading: malformed and unsupported scenes, and what loads correctly
(tests/test_scene_meshes.py: the shapes and mesh files)."""

from __future__ import annotations

import math
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from _scenes import CBOX
from rdsl.runtime.scene import SceneError, load_scene_description, parse_defines, spectra
from rdsl.runtime.scene import transform as xf
from rdsl.runtime.scene.xml import read_scene


def write(path: Path, *lines: str) -> Path:
    path.write_text("\n".join(lines) + "\n")
    return path


def scene(tmp_path: Path, *body: str, name: str = "scene.xml") -> Path:
    """A scene file: line 1 is <scene version="3.0.0">, body starts on line 2."""
    return write(tmp_path / name, '<scene version="3.0.0">', *body, "</scene>")


def load(path: Path, **kw):
    return load_scene_description(path, **kw)


# ---------------------------------------------------------------------------------------
# Malformed and unsupported scenes: (body lines, expected line, expected message part).
# The scene's line 1 is <scene ...>, so the body's first line is line 2.

BAD_SCENES = {
    # a finite number float32 cannot hold would be infinity in the kernels (NaN samples)
    "rgb_beyond_float32": (['<bsdf type="diffuse" id="d">',
                            '  <rgb name="reflectance" value="0.5, 1e40, 0.5"/>', '</bsdf>'], 3,
                           "rgb: 1e40 is too large for a 32-bit float"),
    "float_beyond_float32": (['<bsdf type="roughconductor" id="d">',
                              '  <float name="alpha" value="-4e38"/>', '</bsdf>'], 3,
                             "-4e38 is too large for a 32-bit float"),
    "spectrum_beyond_float32": (['<emitter type="constant">',
                                 '  <spectrum name="radiance" value="400:1, 700:3.5e38"/>',
                                 '</emitter>'], 3, "spectrum: 3.5e38 is too large"),
    "transform_beyond_float32": (['<shape type="sphere">', '  <transform name="to_world">',
                                  '    <scale x="1e39"/>', '  </transform>', '</shape>'], 4,
                                 "attribute x: 1e39 is too large for a 32-bit float"),
    "unclosed_tag": (['<shape type="cube">'], 3, "malformed XML: mismatched tag"),
    "bad_attribute_syntax": (['<shape type=cube/>'], 2, "malformed XML: not well-formed"),
    "unknown_element": (['<camera type="perspective"/>'], 2,
                        "unknown element <camera>; accepted: shape, bsdf"),
    "unknown_shape": (['<shape type="torus"/>'], 2,
                      "unknown shape plugin 'torus'; accepted: rectangle, cube, disk, sphere"),
    "unknown_bsdf": (['<bsdf type="circular" id="p"/>'], 2,
                     "unknown bsdf plugin 'circular'; accepted: diffuse, conductor"),
    "unknown_emitter": (['<emitter type="sunsky"/>'], 2, "unknown emitter plugin 'sunsky'"),
    "unknown_integrator": (['<integrator type="volpath"/>'], 2,
                           "unknown integrator plugin 'volpath'; accepted: path, direct, aov"),
    "unknown_param": (['<bsdf type="diffuse" id="d">',
                       '    <rgb name="reflectanc" value="0.5"/>', '</bsdf>'], 3,
                      "unknown parameter 'reflectanc' of bsdf 'diffuse'; accepted: reflectance"),
    "unknown_param_shape": (['<shape type="sphere">', '    <float name="radus" value="2"/>',
                             '</shape>'], 3,
                            ("unknown parameter 'radus' of shape 'sphere'; accepted: to_world, "
                            "flip_normals, center, radius")),
    "wrong_kind": (['<sensor type="perspective">', '    <string name="fov" value="45"/>',
                    '</sensor>'], 3, ("parameter 'fov' of sensor 'perspective' expects a float, "
                                     "got <string>")),
    "rgb_for_float": (['<shape type="sphere">', '    <rgb name="radius" value="1, 1, 1"/>',
                       '</shape>'], 3, "expects a float, got <rgb>"),
    "bad_float": (['<shape type="sphere">', '    <float name="radius" value="abc"/>',
                   '</shape>'], 3, "<float name=\"radius\">: cannot parse 'abc' as a float"),
    "bad_integer": (['<integrator type="path">', '    <integer name="max_depth" value="8.5"/>',
                     '</integrator>'], 3, "cannot parse '8.5' as an integer"),
    "integer_out_of_range": (['<integrator type="path">',
                              '    <integer name="max_depth" value="999999999999"/>',
                              '</integrator>'], 3,
                             "999999999999 is out of range for an integer (from -2147483648 "
                             "to 2147483647, as in Mitsuba)"),
    "bad_boolean": (['<integrator type="path">',
                     '    <boolean name="hide_emitters" value="yes"/>', '</integrator>'], 3,
                    "expected 'true' or 'false', got 'yes'"),
    "undefined_param": (['<integrator type="path">',
                         '    <integer name="max_depth" value="$depth"/>', '</integrator>'], 3,
                        "undefined parameter '$depth'"),
    "unknown_ref": (['<shape type="cube">', '    <ref id="nothere"/>', '</shape>'], 3,
                    "no object with id 'nothere' is declared in the scene"),
    "duplicate_id": (['<bsdf type="diffuse" id="a"/>', '<bsdf type="diffuse" id="a"/>'], 3,
                     "duplicate id 'a'"),
    "duplicate_param": (['<shape type="sphere">', '    <float name="radius" value="1"/>',
                         '    <float name="radius" value="2"/>', '</shape>'], 4,
                        "parameter 'radius' of shape 'sphere' is given more than once"),
    "missing_obj": (['<shape type="obj">', '    <string name="filename" value="nope.obj"/>',
                     '</shape>'], 3, "shape 'obj': mesh file 'nope.obj' not found"),
    "missing_ply": (['<shape type="ply">', '    <string name="filename" value="m/nope.ply"/>',
                     '</shape>'], 3, "mesh file 'm/nope.ply' not found"),
    "missing_texture": (['<bsdf type="diffuse" id="d">',
                         '    <texture type="bitmap" name="reflectance">',
                         '        <string name="filename" value="wood.png"/>',
                         '    </texture>', '</bsdf>'], 4,
                        "texture 'bitmap': texture file 'wood.png' not found"),
    "missing_filename": (['<shape type="serialized"/>'], 2,
                         "shape 'serialized' is missing the required parameter 'filename'"),
    "medium": (['<medium type="homogeneous" id="m"/>'], 2, "<medium> is not supported by rdsl"),
    "unknown_transform_op": (['<shape type="cube">', '    <transform name="to_world">',
                              '        <skew value="1"/>', '    </transform>', '</shape>'], 4,
                             "<transform>: unknown operation <skew>; accepted: translate, rotate"),
    "rotate_no_angle": (['<shape type="cube">', '    <transform name="to_world">',
                         '        <rotate y="1"/>', '    </transform>', '</shape>'], 4,
                        "<rotate>: missing the 'angle' attribute"),
    "matrix_15": (['<shape type="cube">', '    <transform name="to_world">',
                   '        <matrix value="1 0 0 0 0 1 0 0 0 0 1 0 0 0 0"/>', '    </transform>',
                   '</shape>'], 4, "<matrix>: expected 16 (or 9) values, got 15"),
    "rgb_two_values": (['<bsdf type="diffuse" id="d">', ('    <rgb name="reflectance" '
                        'value="0.5, 0.5"/>'), '</bsdf>'], 3, "rgb: expected 3 values"),
    "rgb_negative": (['<bsdf type="diffuse" id="d">', '    <rgb name="reflectance" '
                      'value="0.5, -0.1, 0.5"/>', '</bsdf>'], 3,
                     "rgb: values must be finite and non-negative"),
    "spectrum_out_of_order": (['<bsdf type="diffuse" id="d">', ('    <spectrum name="reflectance"'
                               ' value="500:0.1, 400:0.2"/>'), '</bsdf>'], 3,
                              ("wavelengths must be strictly increasing, but 400 nm follows "
                              "500 nm")),
    "spectrum_negative": (['<bsdf type="diffuse" id="d">', ('    <spectrum name="reflectance"'
                           ' value="400:0.1, 500:-0.2"/>'), '</bsdf>'], 3,
                          "value -0.2 at 500 nm is negative"),
    "texture_without_name": (['<bsdf type="diffuse" id="d">',
                              '    <texture type="checkerboard"/>', '</bsdf>'], 3,
                             "needs a name=\"...\" attribute"),
    "twosided_three": (['<bsdf type="twosided" id="t">', '    <bsdf type="diffuse"/>',
                        '    <bsdf type="diffuse"/>', '    <bsdf type="diffuse"/>', '</bsdf>'],
                       5, "bsdf 'twosided' takes 1 to 2 nested <bsdf>, got 3"),
    "blend_no_weight": (['<bsdf type="blendbsdf" id="b">', '    <bsdf type="diffuse"/>',
                         '    <bsdf type="diffuse"/>', '</bsdf>'], 2,
                        "bsdf 'blendbsdf' is missing the required parameter 'weight'"),
    "bad_material": (['<bsdf type="conductor" id="c">',
                      '    <string name="material" value="Unobtainium"/>', '</bsdf>'], 3,
                     "conductor material 'Unobtainium' is unknown; accepted: Ag, Al, AlAs, AlAs_palik"),
    "bad_distribution": (['<bsdf type="roughconductor" id="c">',
                          '    <string name="distribution" value="phong"/>', '</bsdf>'], 3,
                         "is 'phong'; accepted: beckmann, ggx"),
    "alpha_u_only": (['<bsdf type="roughconductor" id="c">',
                      '    <float name="alpha_u" value="0.1"/>', '</bsdf>'], 3,
                     "give both 'alpha_u' and 'alpha_v'"),
    "bad_ior_name": (['<bsdf type="dielectric" id="c">',
                      '    <string name="int_ior" value="glass"/>', '</bsdf>'], 3,
                     "unknown index of refraction 'glass'"),
    "area_at_top": (['<emitter type="area"/>'], 2,
                    "an 'area' emitter must be nested inside a <shape>"),
    "point_in_shape": (['<shape type="cube">', '    <emitter type="point"/>', '</shape>'], 3,
                       "only an 'area' emitter can be attached to a shape, not 'point'"),
    "sensor_in_shape": (['<shape type="cube">', '    <sensor type="perspective"/>', '</shape>'],
                        3, "only an 'irradiancemeter' sensor can be nested in a <shape>"),
    "film_at_top": (['<film type="hdrfilm"/>'], 2,
                    "<film> cannot appear directly inside <scene>; nest it inside <sensor>"),
    "bad_crop": (['<sensor type="perspective">', '    <film type="hdrfilm">',
                  '        <integer name="width" value="64"/>',
                  '        <integer name="crop_offset_x" value="60"/>',
                  '        <integer name="crop_width" value="8"/>', '    </film>', '</sensor>'],
                 6, "hdrfilm: invalid crop window: crop_offset_x=60 and crop_width=8 do not fit"),
    "unknown_rfilter": (['<sensor type="perspective">', '    <film type="hdrfilm">',
                         '        <rfilter type="sinc"/>', '    </film>', '</sensor>'], 4,
                        "unknown rfilter plugin 'sinc'; accepted: box, tent, gaussian, "
                        "mitchell, catmullrom, lanczos"),
    "unknown_sampler": (['<sensor type="perspective">', '    <sampler type="sobol"/>',
                         '</sensor>'], 3, ("unknown sampler plugin 'sobol'; accepted: "
                                          "independent, stratified, multijitter, orthogonal")),
    "fov_and_focal": (['<sensor type="perspective">', '    <float name="fov" value="45"/>',
                       '    <string name="focal_length" value="35mm"/>', '</sensor>'], 3,
                      "give either 'fov' or 'focal_length', not both"),
    "camera_scale": (['<sensor type="perspective">', '    <transform name="to_world">',
                      '        <scale value="2"/>', '    </transform>', '</sensor>'], 3,
                     "scale factors in the camera's 'to_world' are not allowed"),
    "thinlens_no_aperture": (['<sensor type="thinlens"/>'], 2,
                             ("sensor 'thinlens' is missing the required parameter "
                             "'aperture_radius'")),
    "unexpected_attribute": (['<shape type="sphere">',
                              '    <float name="radius" value="1" units="m"/>', '</shape>'], 3,
                             "<float>: unexpected attribute 'units'; accepted: name, value"),
    "bad_aov": (['<integrator type="aov">', '    <string name="aovs" value="dd:depthh"/>',
                 '</integrator>'], 3, "aov: bad entry 'dd:depthh'"),
    "bad_max_depth": (['<integrator type="path">', '    <integer name="max_depth" value="-2"/>',
                       '</integrator>'], 3, "'max_depth' must be -1 (infinite) or >= 0"),
    "missing_include": (['<include filename="parts/walls.xml"/>'], 2,
                        "<include>: file 'parts/walls.xml' not found"),
    "bitmap_format": (['<bsdf type="diffuse" id="d">',
                       '    <texture type="bitmap" name="reflectance">',
                       '        <string name="filename" value="tex.gif"/>', '    </texture>',
                       '</bsdf>'], 4, "bitmap: image format '.gif' of 'tex.gif' is not supported"),
    "property_at_top": (['<float name="x" value="1"/>'], 2,
                        "a property must be inside an object"),
    "two_integrators": (['<integrator type="path"/>', '<integrator type="direct"/>'], 3,
                        "more than one <integrator>"),
    "ref_wrong_place": (['<texture type="checkerboard" id="t"/>',
                         '<shape type="cube">', '    <ref id="t"/>', '</shape>'], 4,
                        "needs a name=\"...\" attribute"),
}


@pytest.mark.parametrize("case", sorted(BAD_SCENES))
def test_bad_scene(tmp_path: Path, case: str) -> None:
    body, line, message = BAD_SCENES[case]
    (tmp_path / "tex.gif").write_bytes(b"")
    path = scene(tmp_path, *body)
    with pytest.raises(SceneError) as exc:
        load(path)
    text = str(exc.value)
    assert message in text, text
    assert text.startswith(f"{path}:{line}:"), text


def test_enough_bad_scenes() -> None:
    assert len(BAD_SCENES) >= 25


def test_error_quotes_line_with_caret(tmp_path: Path) -> None:
    path = scene(tmp_path, '  <shape type="torus"/>')
    with pytest.raises(SceneError) as exc:
        load(path)
    lines = str(exc.value).splitlines()
    assert lines[0] == (f"{path}:2:3: error: unknown shape plugin 'torus'; accepted: rectangle, "
                        "cube, disk, sphere, cylinder, sdfgrid, linearcurve, bsplinecurve, obj, "
                        "ply, serialized, shapegroup, instance, merge")
    assert lines[1].strip() == '<shape type="torus"/>'
    assert lines[2].index("^") == lines[1].index("<")


def test_root_and_version_errors(tmp_path: Path) -> None:
    p = write(tmp_path / "a.xml", '<shape type="cube"/>')
    with pytest.raises(SceneError, match="root element must be <scene>"):
        load(p)
    p = write(tmp_path / "b.xml", "<scene>", "</scene>")
    with pytest.raises(SceneError, match=r"b\.xml:1:1: error: <scene>: missing the 'version'"):
        load(p)
    p = write(tmp_path / "c.xml", '<scene version="0.6.0">', "</scene>")
    with pytest.raises(SceneError, match="version 0.6.0 is not supported"):
        load(p)
    with pytest.raises(SceneError, match="scene file .* not found"):
        load(tmp_path / "missing.xml")
    with pytest.raises(SceneError, match="is a folder; expected a Mitsuba 3 XML scene file"):
        load(tmp_path)


def test_errors_in_included_file_name_that_file(tmp_path: Path) -> None:
    write(tmp_path / "part.xml", '<scene version="3.0.0">', '<bsdf type="diffuse" id="d">',
          '    <float name="roughness" value="1"/>', "</bsdf>", "</scene>")
    path = scene(tmp_path, '<include filename="part.xml"/>')
    with pytest.raises(SceneError) as exc:
        load(path)
    assert str(exc.value).startswith(f"{tmp_path / 'part.xml'}:3:")


def test_include_cycle(tmp_path: Path) -> None:
    write(tmp_path / "a.xml", '<scene version="3.0.0">', '<include filename="b.xml"/>',
          "</scene>")
    write(tmp_path / "b.xml", '<scene version="3.0.0">', '<include filename="a.xml"/>',
          "</scene>")
    with pytest.raises(SceneError, match="includes itself"):
        load(tmp_path / "a.xml")


def test_bad_mesh_files_are_named(tmp_path: Path) -> None:
    write(tmp_path / "bad.obj", "v 0 0 0", "v 1 0 0", "f 1 2 7")
    path = scene(tmp_path, '<shape type="obj">', '<string name="filename" value="bad.obj"/>',
                 "</shape>")
    with pytest.raises(SceneError) as exc:
        load(path)
    assert f"{path}:3:" in str(exc.value)
    assert "cannot load mesh file 'bad.obj': line 3: vertex index 7 out of range" in str(exc.value)
    (tmp_path / "bad.serialized").write_bytes(struct.pack("<HH", 0x1234, 4) + b"\0" * 8)
    path = scene(tmp_path, '<shape type="serialized">',
                 '<string name="filename" value="bad.serialized"/>', "</shape>")
    with pytest.raises(SceneError, match="invalid file format identifier 0x1234"):
        load(path)
    write(tmp_path / "bad.ply", "ply", "format binary_middle_endian 1.0", "end_header")
    path = scene(tmp_path, '<shape type="ply">', '<string name="filename" value="bad.ply"/>',
                 "</shape>")
    with pytest.raises(SceneError, match="unsupported PLY format 'binary_middle_endian'"):
        load(path)


# ---------------------------------------------------------------------------------------
# The Cornell box

def test_cbox_loads() -> None:
    s = load(CBOX)
    assert len(s.shapes) == 8
    assert len(s.emitters) == 1 and s.emitters[0] is s.shapes[0].emitter
    assert s.emitters[0]["radiance"].rgb == (18.387, 13.9873, 6.75357)
    assert s.integrator.type == "path" and s.integrator["max_depth"] == 8
    assert s.integrator["rr_depth"] == 5 and s.integrator["hide_emitters"] is False
    film = s.sensor.film
    assert (film["width"], film["height"]) == (256, 256)
    assert (film["crop_width"], film["crop_height"]) == (256, 256)
    assert film["rfilter"].type == "gaussian" and film["rfilter"]["stddev"] == 0.5
    assert s.sensor.sampler["sample_count"] == 64
    cam = np.array([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 3.9], [0, 0, 0, 1]], dtype=float)
    np.testing.assert_allclose(s.sensor["to_world"], cam, atol=1e-12)
    assert s.sensor["fov_x"] == pytest.approx(39.3077)
    assert s.sensor["focus_distance"] == 1000.0 and s.sensor["near_clip"] == 0.001
    assert {sh.id for sh in s.shapes} >= {"light", "floor", "small-box", "large-box"}
    assert s.ids["white"] is s.shapes[1].bsdf and s.ids["red"].type == "diffuse"
    # the light hangs just under the ceiling, facing down
    light = s.shapes[0].mesh
    np.testing.assert_allclose(light.vertices[:, 1], 0.99, atol=1e-6)
    np.testing.assert_allclose(light.normals, np.tile([0, -1, 0], (4, 1)), atol=1e-6)
    v = light.vertices[light.faces[0]].astype(float)
    assert np.cross(v[1] - v[0], v[2] - v[0])[1] < 0
    boxes = [sh for sh in s.shapes if sh.type == "cube"]
    assert all(len(b.mesh.faces) == 12 for b in boxes)


def test_cbox_defines_override_defaults() -> None:
    s = load(CBOX, spp=4, res=128, max_depth=3)
    assert s.sensor.sampler["sample_count"] == 4
    assert s.sensor.film["width"] == 128 and s.integrator["max_depth"] == 3
    assert s.params["spp"] == "4"
    with pytest.warns(UserWarning, match="never used by the scene: sppp"):
        load(CBOX, sppp=4)


def test_parse_defines() -> None:
    assert parse_defines(["spp=16", "name=a=b"]) == {"spp": "16", "name": "a=b"}
    with pytest.raises(SceneError, match="-D expects name=value"):
        parse_defines(["spp"])


# ---------------------------------------------------------------------------------------
# Defaults, include, ref

def test_defaults_and_substitution(tmp_path: Path) -> None:
    path = scene(tmp_path, '<default name="r" value="0.25"/>', '<default name="n" value="7"/>',
                 '<integrator type="path"><integer name="max_depth" value="$n"/></integrator>',
                 '<shape type="sphere" id="s_$n"><float name="radius" value="$r"/></shape>')
    s = load(path)
    assert s.integrator["max_depth"] == 7 and s.shapes[0].id == "s_7"
    assert s.shapes[0]["radius"] == 0.25
    s = load(path, n=2, r="2")
    assert s.integrator["max_depth"] == 2 and s.shapes[0]["radius"] == 2.0


def test_include_and_ref(tmp_path: Path) -> None:
    (tmp_path / "parts").mkdir()
    write(tmp_path / "parts" / "materials.xml", '<scene version="3.0.0">',
          '<default name="albedo" value="0.3"/>',
          '<texture type="checkerboard" id="checks">',
          '    <rgb name="color0" value="0.1, 0.2, 0.3"/>', "</texture>",
          '<bsdf type="diffuse" id="gray"><float name="reflectance" value="$albedo"/></bsdf>',
          "</scene>")
    path = scene(tmp_path, '<include filename="parts/materials.xml"/>',
                 '<bsdf type="diffuse" id="checked"><ref name="reflectance" id="checks"/></bsdf>',
                 '<shape type="rectangle"><ref id="gray"/></shape>',
                 '<shape type="disk"><ref name="bsdf" id="checked"/></shape>',
                 '<shape type="cube"><ref id="gray"/></shape>')
    s = load(path)
    a, b, c = s.shapes
    assert a.bsdf is c.bsdf is s.ids["gray"]
    assert a.bsdf["reflectance"].rgb == (0.3, 0.3, 0.3)
    tex = b.bsdf["reflectance"]
    assert tex is s.ids["checks"] and tex.type == "checkerboard"
    assert tex["color0"].rgb == (0.1, 0.2, 0.3) and tex["color1"].rgb == (0.2, 0.2, 0.2)
    assert s.integrator.type == "path" and s.sensor.type == "perspective"  # defaults
    assert s.sensor.film["width"] == 768 and s.sensor.sampler["sample_count"] == 4


def test_path_element_and_nested_objects(tmp_path: Path) -> None:
    (tmp_path / "meshes").mkdir()
    write(tmp_path / "meshes" / "tri.obj", "v 0 0 0", "v 1 0 0", "v 0 1 0", "f 1 2 3")
    (tmp_path / "img.png").write_bytes(b"")
    path = scene(tmp_path, '<path value="meshes"/>',
                 '<shape type="obj">', '    <string name="filename" value="tri.obj"/>',
                 '    <bsdf type="twosided">', '        <bsdf type="roughplastic">',
                 '            <texture type="bitmap" name="diffuse_reflectance">',
                 '                <string name="filename" value="img.png"/>',
                 '                <string name="filter_type" value="nearest"/>',
                 '                <transform name="to_uv"><scale x="2" y="3"/></transform>',
                 '            </texture>', '        </bsdf>', '    </bsdf>',
                 '    <emitter type="area"><spectrum name="radiance" value="2"/></emitter>',
                 '</shape>')
    s = load(path)
    sh = s.shapes[0]
    assert sh.bsdf.type == "twosided" and sh.bsdf.children[0].type == "roughplastic"
    rp = sh.bsdf.children[0]
    assert rp["int_ior"] == 1.49 and rp["ext_ior"] == 1.00028 and rp["alpha"] == 0.1
    tex = rp["diffuse_reflectance"]
    assert tex["filter_type"] == "nearest" and tex["wrap_mode"] == "repeat"
    np.testing.assert_allclose(np.diag(tex["to_uv"]), [2, 3, 1, 1])
    assert tex["filename"] == str(tmp_path / "img.png")
    # a constant <spectrum> radiance is the flat spectrum: Mitsuba 3's scalar_rgb loads it as
    # 2 x (1.204794, 0.948291, 0.908916), the equal-energy white, not as grey 2
    np.testing.assert_allclose(sh.emitter["radiance"].rgb, [2.409588, 1.896582, 1.817832],
                               rtol=1e-3)
    assert s.emitters == [sh.emitter]


def test_bsdf_parameters_resolved(tmp_path: Path) -> None:
    path = scene(tmp_path,
                 '<bsdf type="roughconductor" id="rc"><string name="material" value="Au"/>',
                 '  <string name="distribution" value="ggx"/>',
                 '  <float name="alpha" value="0.2"/></bsdf>',
                 '<bsdf type="roughconductor" id="an"><float name="alpha_u" value="0.1"/>',
                 '  <float name="alpha_v" value="0.3"/><rgb name="eta" value="1,1,1"/></bsdf>',
                 '<bsdf type="conductor" id="mirror"/>',
                 '<bsdf type="dielectric" id="glass"><string name="int_ior" value="water"/>',
                 '  <float name="ext_ior" value="1"/></bsdf>',
                 '<bsdf type="mask" id="m"><float name="opacity" value="0.3"/>',
                 '  <ref id="glass"/></bsdf>',
                 '<bsdf type="blendbsdf" id="b"><float name="weight" value="0.25"/>',
                 '  <ref id="rc"/><ref id="mirror"/></bsdf>',
                 '<bsdf type="plastic" id="p"/><bsdf type="thindielectric" id="t"/>')
    ids = load(path).ids
    rc = ids["rc"]
    assert rc["alpha"] == 0.2 and rc["alpha_u"] is rc["alpha_v"] is None  # isotropic
    assert rc["distribution"] == "ggx"
    assert rc["eta"].wavelengths is not None and rc["k"].rgb[0] > 3
    an = ids["an"]
    assert (an["alpha_u"], an["alpha_v"]) == (0.1, 0.3) and an["k"].rgb == (1.0, 1.0, 1.0)
    assert an["distribution"] == "beckmann"
    assert ids["mirror"]["eta"].rgb == (0, 0, 0) and ids["mirror"]["k"].rgb == (1, 1, 1)
    assert ids["glass"]["int_ior"] == 1.333 and ids["glass"]["eta"] == pytest.approx(1.333)
    assert ids["m"].children == [ids["glass"]] and ids["m"]["opacity"] == 0.3
    assert ids["b"].children == [ids["rc"], ids["mirror"]] and ids["b"]["weight"] == 0.25
    assert ids["p"]["int_ior"] == 1.49 and ids["p"]["diffuse_reflectance"].rgb == (.5, .5, .5)
    assert ids["t"]["int_ior"] == 1.5046


def test_emitters_integrators_sensors(tmp_path: Path) -> None:
    (tmp_path / "sky.exr").write_bytes(b"")
    path = scene(tmp_path,
                 '<emitter type="point"><point name="position" x="1" y="2" z="3"/></emitter>',
                 '<emitter type="spot"><float name="cutoff_angle" value="40"/></emitter>',
                 '<emitter type="directional"><vector name="direction" value="0, -1, 0"/>',
                 '</emitter>', '<emitter type="constant"/>',
                 '<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>',
                 '<integrator type="aov"><string name="aovs" value="d:depth, n:sh_normal"/>',
                 '  <integrator type="direct"><integer name="shading_samples" value="4"/>',
                 '  </integrator></integrator>',
                 '<sensor type="thinlens"><float name="aperture_radius" value="0.1"/>',
                 '  <float name="fov" value="30"/><string name="fov_axis" value="y"/>',
                 '  <film type="hdrfilm"><integer name="width" value="200"/>',
                 '    <integer name="height" value="100"/><rfilter type="tent"/></film>',
                 '</sensor>', '<sensor type="perspective"/>')
    s = load(path)
    pt, spot, dr, const, env = s.emitters
    np.testing.assert_allclose(pt["position"], [1, 2, 3])
    assert spot["beam_width"] == 30.0 and spot["intensity"].rgb == (1.0, 1.0, 1.0)
    np.testing.assert_allclose(dr["direction"], [0, -1, 0], atol=1e-12)
    assert const["radiance"].rgb == (1.0, 1.0, 1.0) and env["scale"] == 1.0
    assert s.integrator["aov_list"] == [("d", "depth"), ("n", "sh_normal")]
    inner = s.integrator.children[0]
    assert inner["emitter_samples"] == inner["bsdf_samples"] == 4
    cam = s.sensors[0]
    assert cam.film["rfilter"].type == "tent" and cam.film["rfilter"]["radius"] == 1.0
    expect = 2 * math.degrees(math.atan(math.tan(math.radians(15)) * 2))
    assert cam["fov_x"] == pytest.approx(expect)
    assert cam["focus_distance"] == 1e4 and cam["aperture_radius"] == 0.1
    # perspective with neither fov nor focal_length: 50mm on the diagonal, 768x576 film
    d = 2 * math.tan(math.atan(math.hypot(36, 24) / 100))
    w = d / math.sqrt(1 + 1 / (768 / 576) ** 2)
    assert s.sensors[1]["fov_x"] == pytest.approx(2 * math.degrees(math.atan(w / 2)))


# ---------------------------------------------------------------------------------------
# Transforms

def _to_world(tmp_path: Path, *ops: str) -> np.ndarray:
    path = scene(tmp_path, '<shape type="rectangle"><transform name="to_world">', *ops,
                 "</transform></shape>")
    return load(path).shapes[0]["to_world"]


def test_transform_composition(tmp_path: Path) -> None:
    m = _to_world(tmp_path, '<scale x="2" y="3" z="4"/>', '<rotate z="1" angle="90"/>',
                  '<translate x="1" y="2" z="3"/>')
    expect = np.array([[0, -3, 0, 1], [2, 0, 0, 2], [0, 0, 4, 3], [0, 0, 0, 1]], dtype=float)
    np.testing.assert_allclose(m, expect, atol=1e-12)
    m = _to_world(tmp_path, '<translate value="1 0 0"/>', '<scale value="2"/>')
    np.testing.assert_allclose(m @ [0, 0, 0, 1], [2, 0, 0, 1])  # translated, then scaled


def test_rotate_matches_right_handed_rodrigues(tmp_path: Path) -> None:
    m = _to_world(tmp_path, '<rotate x="1" angle="90"/>')
    np.testing.assert_allclose(m[:3, :3] @ [0, 0, 1], [0, -1, 0], atol=1e-12)
    m = _to_world(tmp_path, '<rotate value="1, 1, 1" angle="120"/>')
    np.testing.assert_allclose(m[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_matrix_and_lookat(tmp_path: Path) -> None:
    vals = " ".join(str(v) for v in range(1, 13)) + " 0 0 0 1"
    m = _to_world(tmp_path, f'<matrix value="{vals}"/>')
    np.testing.assert_allclose(m[0], [1, 2, 3, 4])
    np.testing.assert_allclose(m[2], [9, 10, 11, 12])
    m = xf.look_at([1, 2, 3], [1, 2, 4], [0, 1, 0])
    np.testing.assert_allclose(m, [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]],
                               atol=1e-12)
    m = xf.look_at([0, 0, 0], [0, -5, 0])  # no up given: any perpendicular frame
    np.testing.assert_allclose(m[:3, 2], [0, -1, 0])
    np.testing.assert_allclose(m[:3, :3].T @ m[:3, :3], np.eye(3), atol=1e-12)


@pytest.mark.parametrize("origin,target", [((0, 0.5, 4), (0, 0, 0)), ((2.5, 1, 3), (0.5, 0, 0)),
                                           ((0, 0, 0), (0, 0, 1)), ((0, 0, 0), (1, 2, 3)),
                                           ((0, 0, 0), (0, -5, 0))])
def test_lookat_without_up_is_mitsubas(origin, target) -> None:
    """A <lookat> without `up` gets the frame Mitsuba 3's parser gives it (the first vector
    of coordinate_system(dir) as up): a spot light's projected texture turns with it."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    o, t = ", ".join(map(str, origin)), ", ".join(map(str, target))
    scene = mi.load_string(f'<scene version="3.0.0"><sensor type="perspective"><transform '
                           f'name="to_world"><lookat origin="{o}" target="{t}"/></transform>'
                           '</sensor></scene>')
    theirs = np.array(scene.sensors()[0].world_transform().matrix, np.float64)
    np.testing.assert_allclose(xf.look_at(origin, target), theirs, atol=1e-6)


# ---------------------------------------------------------------------------------------
# Spectra

def test_spectrum_parsing() -> None:
    from rdsl.compiler.ir import Loc
    loc = Loc("x.xml", 1, 1)
    assert spectra.parse_spectrum("0.5", loc).rgb == (0.5, 0.5, 0.5)
    c = spectra.parse_spectrum("400:0.5, 500:0.5 600:0.5, 700:0.5", loc)
    assert c.wavelengths == (400, 500, 600, 700) and c.values == (0.5,) * 4
    red = spectra.parse_spectrum("600:1, 700:1", loc)
    assert red.rgb[0] > 0.3 and red.rgb[2] == 0.0
    assert spectra.parse_rgb("0.1 0.2 0.3", loc).rgb == (0.1, 0.2, 0.3)
    assert spectra.parse_rgb("0.7", loc).rgb == (0.7, 0.7, 0.7)
    for bad, msg in [("400:1, 400:2", "strictly increasing"), ("400:1, 500", "not a"),
                     ("-1", "negative"), ("400:a, 500:1", "cannot parse"),
                     ("400:1", "at least two")]:
        with pytest.raises(SceneError, match=msg):
            spectra.parse_spectrum(bad, loc)


def test_unit_spectrum_has_unit_luminance() -> None:
    xyz = spectra.spectrum_to_xyz(np.array([300.0, 900.0]), np.array([1.0, 1.0]))
    assert xyz[1] == pytest.approx(1.0, rel=2e-3)  # Mitsuba: 1.000999
    assert xyz[0] == pytest.approx(1.0, abs=0.02) and xyz[2] == pytest.approx(1.0, abs=0.02)


def test_conductor_rgb_matches_mitsuba() -> None:
    from rdsl.compiler.ir import Loc
    eta, k = spectra.conductor_ior("Cu", Loc("x", 1, 1))
    np.testing.assert_allclose(eta.rgb, (0.200438, 0.924033, 1.10221), rtol=5e-3)
    np.testing.assert_allclose(k.rgb, (3.91295, 2.45285, 2.14219), rtol=5e-3)
    eta, k = spectra.conductor_ior("Ag", Loc("x", 1, 1))  # Mitsuba 3: 0.1553 0.1167 0.1384
    np.testing.assert_allclose(eta.rgb, (0.15528, 0.11673, 0.13839), rtol=5e-3)


def test_spectrum_file(tmp_path: Path) -> None:
    write(tmp_path / "s.spd", "# comment", "400 0.2", "500 0.4", "600 0.6")
    path = scene(tmp_path, '<bsdf type="diffuse" id="d">',
                 '<spectrum name="reflectance" filename="s.spd"/></bsdf>')
    c = load(path).ids["d"]["reflectance"]
    assert c.wavelengths == (400, 500, 600) and max(c.rgb) <= 1.0


def test_read_scene_tree_keeps_lines(tmp_path: Path) -> None:
    path = scene(tmp_path, "", '<bsdf type="diffuse" id="d">',
                 '    <rgb name="reflectance" value="1 0 0"/>', "</bsdf>")
    tree = read_scene(path)
    node = tree.ids["d"]
    assert node.loc.line == 3 and node.props["reflectance"].loc.line == 4


@pytest.mark.parametrize("prop,warns", [
    ('<rgb name="reflectance" value="0.5, 1.25, 0.5"/>', True),
    ('<spectrum name="reflectance" value="400:0.5, 700:1.5"/>', True),
    ('<float name="reflectance" value="3"/>', True),
    ('<rgb name="reflectance" value="1, 1, 1"/>', False),
    ('<spectrum name="reflectance" value="3.4e38"/>', True),  # the largest float32 is taken
])
def test_reflectance_above_one_warns_at_its_line(tmp_path: Path, prop: str, warns: bool):
    path = scene(tmp_path, '<bsdf type="diffuse" id="d">', "", f"  {prop}", "</bsdf>")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        load(path)
    got = [str(x.message) for x in w if "above 1" in str(x.message)]
    assert len(got) == warns, got
    assert all(g.startswith(f"{path}:4: reflectance ") for g in got), got


def test_cli_prints_a_scene_warning_without_rdsl_paths(tmp_path: Path, capsys):
    pytest.importorskip("rdsl.runtime.embree")
    from rdsl.cli import main

    path = scene(tmp_path, '<shape type="sphere"><bsdf type="diffuse">',
                 '<rgb name="reflectance" value="1.5"/></bsdf></shape>',
                 '<emitter type="constant"/>', '<sensor type="perspective"><film type="hdrfilm">',
                 '<integer name="width" value="4"/><integer name="height" value="4"/>',
                 '</film></sensor>')
    assert main(["render", str(path), "--spp", "1", "-o", str(tmp_path / "o.exr"),
                 "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"warning: {path}:3: reflectance 1.5 is above 1" in err
    assert "rdsl" not in err.replace(str(tmp_path), "") and "Warning:" not in err, err
