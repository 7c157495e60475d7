"""Integrators as plugins (docs/plugins.md): the `Scene` handle, user integrators in scenes,
AOVs, nesting, and each mistake a clear error.

Independent truths: a copy of the stdlib `path` integrator under another name renders the
stdlib image bit for bit (and tests/test_bit_identical.py holds the stdlib integrators, now
plugins, to the images of the build before they were); the ambient-occlusion example
(examples/plugins/ao.rdsl) is 1 on an open plane and follows the closed form
1 - (acos(a) - a sqrt(1 - a^2)) / pi, a = d / max_distance, at distance d from a wall.
"""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _scenes import CBOX
from rdsl.compiler.diagnostics import CompileError

ROOT = Path(__file__).resolve().parents[1]
AO = ROOT / "examples" / "plugins" / "ao.rdsl"
HEADER = '<scene version="3.0.0">\n'


def _camera(origin: str, target: str, fov: float, width: int, height: int, spp: int) -> str:
    return f"""
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <string name="fov_axis" value="x"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="{width}"/><integer name="height" value="{height}"/>
            <rfilter type="box"/>
        </film>
    </sensor>"""


FLOOR = """
    <shape type="rectangle">
        <transform name="to_world"><scale value="10"/><translate x="10"/></transform>
    </shape>"""
# the plane x = 0, facing +x, standing on the floor's edge
WALL = """
    <shape type="rectangle">
        <transform name="to_world"><rotate y="1" angle="90"/><scale value="10"/></transform>
    </shape>"""


def write_scene(folder: Path, body: str, name: str = "scene.xml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(HEADER + body + "\n</scene>\n")
    return path


def ao_integrator(samples: int = 4, max_distance: float = 1.0) -> str:
    return f"""
    <integrator type="ao">
        <integer name="samples" value="{samples}"/>
        <float name="max_distance" value="{max_distance}"/>
    </integrator>"""


def test_ao_open_plane_is_one(tmp_path):
    (tmp_path / "ao.rdsl").write_text(AO.read_text())
    path = write_scene(tmp_path, ao_integrator() + FLOOR
                       + _camera("5, 0, 3", "5, 0, 0", 40, 16, 16, 4))
    img = rdsl.load_scene(path).render()
    assert img.shape == (16, 16, 3)
    np.testing.assert_allclose(img, 1.0, atol=1e-6)


def test_ao_corner_matches_closed_form(tmp_path):
    """AO on the floor beside a wall, against the closed form at each pixel's position
    (the `aov` integrator, wrapping the user's `ao`, writes the positions)."""
    (tmp_path / "ao.rdsl").write_text(AO.read_text())
    wrapped = ao_integrator(4, 1.0).replace(
        '<integrator type="ao">',
        '<integrator type="aov"><string name="aovs" value="p:position"/>'
        '<integrator type="ao">') + "</integrator>"
    path = write_scene(tmp_path, wrapped + FLOOR + WALL
                       + _camera("0.55, 0, 2", "0.55, 0, 0", 28, 48, 16, 64))
    scene = rdsl.load_scene(path)
    img = scene.render(seed=3)
    # as Mitsuba's aov: the nested integrator's image (_arg_0.R ... .A), then the AOVs
    assert scene.channel_names == ["R", "G", "B", "_arg_0.R", "_arg_0.G", "_arg_0.B",
                                   "_arg_0.A", "p.X", "p.Y", "p.Z"]
    np.testing.assert_array_equal(img[..., 3:6], img[..., :3])
    ao, x = img[..., 0], img[..., 7]
    assert 0.03 < x.min() and x.max() < 1.1 and np.allclose(img[..., 9], 0.0, atol=1e-5)
    a = np.clip(x, 0.0, 1.0)
    expected = 1.0 - (np.arccos(a) - a * np.sqrt(1.0 - a * a)) / np.pi
    col_ao, col_expected = ao.mean(axis=0), expected.mean(axis=0)
    n = 16 * 64 * 4  # occlusion rays per column
    sigma = np.sqrt(np.maximum(col_expected * (1 - col_expected), 1e-4) / n)
    assert np.all(np.abs(col_ao - col_expected) < 5 * sigma + 2e-3), \
        np.abs(col_ao - col_expected) / sigma
    # the profile covers the interesting range: near the wall to the open floor
    assert col_expected.min() < 0.6 and col_expected.max() > 0.99


@pytest.mark.skipif(not CBOX.is_file(), reason=f"{CBOX} is not present")
def test_user_copy_of_path_is_bit_identical(tmp_path):
    src = (ROOT / "stdlib" / "integrator" / "path.rdsl").read_text()
    mine = re.sub(r"^integrator path \{", "integrator mypath {", src, flags=re.MULTILINE)
    assert mine != src
    (tmp_path / "mypath.rdsl").write_text(mine)
    text = CBOX.read_text().replace('<integrator type="path">', '<integrator type="mypath">')
    (tmp_path / "cbox.xml").write_text(text)
    small = {"res": 24, "spp": 4, "max_depth": 5}
    ours = rdsl.load_scene(tmp_path / "cbox.xml", **small).render(seed=1)
    stdlib = rdsl.load_scene(CBOX, **small).render(seed=1)
    assert np.array_equal(ours, stdlib)


AOV_PLUGIN = """
import render.integrator;

struct Extra { hit: Float, n: Vec3, tint: Spectrum }

integrator extras {
    param tint: Spectrum = Spectrum(0.25, 0.5, 1.0);

    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> (Spectrum, Extra) {
        let h = scene.trace(ray);
        if !h.valid {
            return (Spectrum(0.0), Extra { hit: 0.0, n: Vec3(0.0), tint: Spectrum(0.0) });
        }
        let it = scene.interaction(ray, h);
        return (Spectrum(h.t), Extra { hit: 1.0, n: it.ng, tint: tint });
    }
}
"""


def test_user_integrator_aovs_are_channels(tmp_path):
    (tmp_path / "extras.rdsl").write_text(AOV_PLUGIN)
    path = write_scene(tmp_path, '<integrator type="extras"/>' + FLOOR
                       + _camera("5, 0, 3", "5, 0, 0", 40, 8, 8, 2))
    scene = rdsl.load_scene(path)
    img = scene.render()
    assert scene.channel_names == ["R", "G", "B", "hit", "n.X", "n.Y", "n.Z",
                                   "tint.R", "tint.G", "tint.B"]
    np.testing.assert_allclose(img[..., 3], 1.0, atol=1e-6)
    np.testing.assert_allclose(img[..., 4:7], np.broadcast_to([0, 0, 1], (8, 8, 3)), atol=1e-6)
    np.testing.assert_allclose(img[..., 7:10], np.broadcast_to([0.25, 0.5, 1], (8, 8, 3)),
                               atol=1e-6)
    # the radiance is the hit distance from the near plane (near_clip 0.01): 2.99 straight
    # down, a little more off axis
    assert 2.99 - 1e-3 < img[..., 0].min() and img[..., 0].max() < 2.99 * 1.13


def test_integrator_param_from_xml_and_generic_build(tmp_path):
    """A user integrator's param set in the XML, specialized and read at run time."""
    (tmp_path / "ao.rdsl").write_text(AO.read_text())
    body = ao_integrator(2, 1.0).replace(
        '<float name="max_distance" value="1.0"/>',
        '<float name="max_distance" value="1.0"/><float name="background" value="0.25"/>')
    path = write_scene(tmp_path, body + _camera("5, 0, 3", "5, 0, 0", 40, 8, 8, 2))
    for specialize in (True, False):
        img = rdsl.load_scene(path, specialize=specialize).render()
        np.testing.assert_allclose(img, 0.25, atol=1e-6)


def _errors(tmp_path: Path, plugin: str, xml: str = '<integrator type="mine"/>') -> str:
    (tmp_path / "mine.rdsl").write_text(textwrap.dedent(plugin))
    path = write_scene(tmp_path, xml + FLOOR + _camera("5, 0, 3", "5, 0, 0", 40, 4, 4, 1))
    with pytest.raises(CompileError) as e:
        rdsl.load_scene(path).compile()
    return str(e.value)


GOOD = """
    import render.integrator;
    integrator mine {
        param k: Float = 1.0;
        fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum {
            let h = scene.trace(ray);
            return Spectrum(k);
        }
    }
"""


@pytest.mark.parametrize("plugin, message", [
    (GOOD.replace("fn sample(", "fn li("), "missing the required function `fn sample("),
    (GOOD.replace("sampler: Sampler) -> Spectrum", "sampler: Sampler) -> Float")
     .replace("return Spectrum(k);", "return k;"), "`mine.sample` has the wrong signature"),
    (GOOD.replace("import render.integrator;", ""),
     "unknown type `Scene`; it is declared in the stdlib: add `import render.integrator;`"),
    (GOOD.replace("return Spectrum(k);", "return Spectrum(scene.P[0]);"),
     "field `P` of `Scene` is a buffer, private to"),
    (GOOD.replace("return Spectrum(k);", "return Spectrum(k) * sampler.next_3d();"),
     "unknown function `next_3d`"),
])
def test_integrator_mistakes_are_diagnostics(tmp_path, plugin, message):
    text = _errors(tmp_path, plugin)
    assert message in text, text
    assert "mine.rdsl" in text


def test_integrator_xml_mistakes(tmp_path):
    text = _errors(tmp_path, GOOD, '<integrator type="mine"><float name="kk" value="1"/>'
                   '</integrator>')
    assert "kk" in text and "mine.rdsl:3" in text, text
    text = _errors(tmp_path, GOOD, '<integrator type="mine"><integrator type="path"/>'
                   '</integrator>')
    assert "nests no other one" in text, text


def test_a_texture_on_an_integrators_param_is_an_error_at_the_texture(tmp_path):
    plugin = GOOD.replace("param k: Float = 1.0;", "param k: Float = 1.0;\n"
                          "        param tint: Texture = 0.5;")
    xml = ('<integrator type="mine">\n<texture type="checkerboard" name="tint"/>'
           '</integrator>')
    text = _errors(tmp_path, plugin, xml)
    assert "a texture cannot set `tint` here (an integrator's params take constant colours, "\
        "not textures)" in text, text
    assert f"{tmp_path / 'scene.xml'}:3:1:" in text or "scene.xml:3:1:" in text, text


def test_integrator_aov_field_types_are_checked(tmp_path):
    plugin = AOV_PLUGIN.replace("hit: Float,", "hit: Int,").replace("hit: 0.0", "hit: 0") \
        .replace("hit: 1.0", "hit: 1").replace("extras", "mine")
    text = _errors(tmp_path, plugin)
    assert "AOV field `Extra.hit`" in text and "has type `Int`" in text, text


def test_test_plugin_passes_ao_and_catches_a_nan(tmp_path, capsys):
    from rdsl.cli import main

    assert main(["test-plugin", str(AO)]) == 0
    out = capsys.readouterr().out
    assert "finite, >= 0" in out and "deterministic" in out and "0 failed" in out
    bad = GOOD.replace("return Spectrum(k);",
                       "return Spectrum(select(h.t > 4.0, k / 0.0 - k / 0.0, k));")
    (tmp_path / "mine.rdsl").write_text(textwrap.dedent(bad))
    assert main(["test-plugin", str(tmp_path / "mine.rdsl")]) == 1
    assert "NaN or infinite samples" in capsys.readouterr().out


def test_two_channel_film_in_mono(tmp_path):
    """mono + one Float AOV is a film of two channels (a layout the film once mixed up with
    its weight column)."""
    plugin = AOV_PLUGIN.replace("struct Extra { hit: Float, n: Vec3, tint: Spectrum }",
                                "struct Extra { hit: Float }") \
        .replace(", n: Vec3(0.0), tint: Spectrum(0.0)", "").replace(", n: it.ng, tint: tint", "")
    (tmp_path / "extras.rdsl").write_text(plugin)
    path = write_scene(tmp_path, '<integrator type="extras"/>' + FLOOR
                       + _camera("5, 0, 3", "5, 0, 0", 40, 8, 8, 2))
    scene = rdsl.load_scene(path, variant="mono")
    img = scene.render()
    assert scene.channel_names == ["Y", "hit"]
    np.testing.assert_allclose(img[..., 1], 1.0, atol=1e-6)
    assert 2.99 - 1e-3 < img[..., 0].min() and img[..., 0].max() < 2.99 * 1.13


def test_depth_integrator_matches_mitsuba(tmp_path):
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    body = ('<integrator type="depth"/>' + FLOOR + WALL
            + _camera("0.55, 0.2, 2", "0.3, 0, 0", 60, 12, 10, 64)
            .replace('<rfilter type="box"/>', '<rfilter type="box"/>'
                     '<string name="pixel_format" value="rgb"/>'))
    path = write_scene(tmp_path, body)
    ours = rdsl.load_scene(path).render(seed=0)
    theirs = np.array(mi.render(mi.load_file(str(path)), spp=64))
    assert ours.shape == theirs.shape
    assert 0.5 < ours.max() and ours.min() >= 0
    # per pixel means of the distance over the footprint: equal within the sampling noise
    # (64 spp each: about 0.03 where a pixel straddles the wall's edge)
    np.testing.assert_allclose(ours, theirs, rtol=0.01, atol=0.06)
    assert abs(ours.mean() - theirs.mean()) < 0.005 * theirs.mean()


def test_test_plugin_passes_the_stdlib_path_integrator(capsys):
    """The stdlib's `path` given as a file is a plugin like a user's (its params declared in
    rdsl, not Mitsuba's schema)."""
    from rdsl.cli import main

    assert main(["test-plugin", str(ROOT / "stdlib" / "integrator" / "path.rdsl")]) == 0
    assert "0 failed" in capsys.readouterr().out
