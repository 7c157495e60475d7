"""Mitsuba 3's `volume` texture (stdlib/texture/volume.rdsl; its `gridvolume` and
`constvolume`: runtime/scene/volumes.py) against Mitsuba 3 itself: the texture's values at
points inside and outside its volume (trilinear and nearest, each wrap mode, a one- and a
three-channel grid, a moved volume, the grid's own bounding box), and a render with a
colour and a Float parameter set by volumes; bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rdsl
from _mitsuba_render import mitsuba_variant
from _plugin_scenes import median_rmse, write_scene
from rdsl.runtime.render.textures import TextureTable
from rdsl.runtime.scene import SceneError, load_scene_description
from rdsl.runtime.scene.volgrid import write_vol

f32 = np.float32
MOVED = ('<transform name="to_world"><scale x="2" y="1.5" z="1"/><rotate y="1" angle="30"/>'
         '<translate x="-1" y="-0.7" z="-0.4"/></transform>')
# (the gridvolume's contents, whether it reads the three-channel grid)
CASES = [
    ("", True),
    ('<string name="filter_type" value="nearest"/>', True),
    ('<string name="wrap_mode" value="repeat"/>', False),
    ('<string name="wrap_mode" value="mirror"/><string name="filter_type" value="nearest"/>',
     False),
    (MOVED, True),
    ('<boolean name="use_grid_bbox" value="true"/>' + MOVED, False),
]


def _grids(folder: Path) -> None:
    rng = np.random.default_rng(5)
    write_vol(folder / "c3.vol", rng.random((3, 4, 5, 3)).astype(f32))
    write_vol(folder / "c1.vol", (rng.random((4, 3, 2)) * 2).astype(f32),
              bbox=(-0.5, 0.2, 0.0, 1.0, 0.6, 2.0))


def _texture(folder: Path, body: str, three: bool, name: str = "reflectance") -> str:
    return (f'<texture type="volume" name="{name}"><volume type="gridvolume" name="volume">'
            f'<string name="filename" value="{folder / ("c3.vol" if three else "c1.vol")}"/>'
            f'{body}</volume></texture>')


PROBE = """
import texture.volume;
fn probe(p: Vec3, T: [Float]) -> Vec4 {{
    let si = Surface {{ p: p, n: Vec3(0.0, 0.0, 1.0), sh_n: Vec3(0.0, 0.0, 1.0),
                       uv: Vec2(0.0, 0.0), wi: Vec3(0.0, 0.0, 1.0), t: 1.0, valid: true,
                       prim: -1, bary: Vec2(0.0, 0.0) }};
    let c = volume_eval_3_buffers(si, T, {offset}, {nx}, {ny}, {nz}, {filter}, {wrap},
                                  Vec4{r0}, Vec4{r1}, Vec4{r2});
    let one = volume_eval_1_buffers(si, T, {offset}, {nx}, {ny}, {nz}, {filter}, {wrap},
                                    Vec4{r0}, Vec4{r1}, Vec4{r2}, {const}, Vec3{rgb},
                                    {spectral_mean});
    return Vec4(c.x, c.y, c.z, one);
}}
"""


def _compare(tmp_path: Path, texture: str, points: np.ndarray) -> None:
    """rdsl's RGB and one value of ``texture`` (a volume texture's XML) at ``points`` against
    Mitsuba's, to float rounding."""
    path = tmp_path / "v.xml"
    path.write_text(f'<scene version="3.0.0"><shape type="sphere"><bsdf type="diffuse">'
                    f'{texture}</bsdf></shape></scene>')
    tex = load_scene_description(path).shapes[0].bsdf.params["reflectance"]
    table = TextureTable()
    inst = table.instances[table.ref(tex, "reflectance", "scalar").index]
    params = {**inst.params, "const": str(inst.params["constant"]).lower()}
    mod = rdsl.jit(PROBE.format(**params), target="host", variant="rgb")
    ours = np.asarray(mod["probe"](points, table.buffer()), np.float64)
    with mitsuba_variant("scalar_rgb") as mi:
        theirs_tex = mi.load_string(texture.replace("<texture ", '<texture version="3.0.0" ', 1))
        si = mi.SurfaceInteraction3f()
        theirs = []
        for q in points:
            si.p = [float(x) for x in q]
            theirs.append([*np.array(theirs_tex.eval(si), np.float64), theirs_tex.eval_1(si)])
    np.testing.assert_allclose(ours, np.array(theirs), atol=2e-6, rtol=2e-5)


@pytest.mark.parametrize("case", range(len(CASES)))
def test_values_match_mitsubas(tmp_path, case):
    """At 2000 points in and around the volume's box, the texture's RGB (and its one value)
    is Mitsuba's, to float rounding."""
    _grids(tmp_path)
    body, three = CASES[case]
    p = (np.random.default_rng(case).random((2000, 3)) * 5 - 2.5).astype(f32)
    _compare(tmp_path, _texture(tmp_path, body, three), p)


def test_constvolume_matches_mitsubas(tmp_path):
    """A constvolume: its colour everywhere, and as one value what Mitsuba's srgb texture
    gives (the channels' mean in rgb builds, not the luminance)."""
    const = ('<texture type="volume" name="reflectance"><volume type="constvolume" '
             'name="volume"><rgb name="value" value="0.1, 0.3, 0.8"/></volume></texture>')
    _compare(tmp_path, const, (np.random.default_rng(0).random((50, 3)) * 9 - 4).astype(f32))


def test_render_matches_mitsuba(tmp_path):
    """A sphere coloured by a moved three-channel grid, a rough conductor whose roughness is
    a repeated one-channel grid (eval_1) and a sphere coloured by a constvolume, in the test
    room: rdsl's median RMSE within 1.2x of Mitsuba's at 32 spp, against 4096 spp."""
    _grids(tmp_path)
    rough = _texture(tmp_path, '<string name="wrap_mode" value="repeat"/><transform '
                     'name="to_world"><scale value="0.3"/></transform>', False, "alpha")
    const = ('<texture type="volume" name="reflectance"><volume type="constvolume" '
             'name="volume"><rgb name="value" value="0.1, 0.3, 0.8"/></volume></texture>')
    body = (f'<shape type="sphere"><float name="radius" value="0.7"/><point name="center" '
            f'x="-0.5" y="0.3" z="0"/><bsdf type="diffuse">{_texture(tmp_path, MOVED, True)}'
            f'</bsdf></shape>'
            f'<shape type="rectangle"><transform name="to_world"><scale value="0.8"/>'
            f'<rotate x="1" angle="-50"/><translate x="0.8" y="-0.6" z="0.2"/></transform>'
            f'<bsdf type="roughconductor">{rough}</bsdf></shape>'
            f'<shape type="sphere"><float name="radius" value="0.3"/><point name="center" '
            f'x="0.9" y="0.8" z="0"/><bsdf type="diffuse">{const}</bsdf></shape>')
    mine, theirs = median_rmse(write_scene(tmp_path, body), 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


# (what the volume texture holds, on line 3; the error's line; the message)
BAD = {
    "missing file": (('<volume type="gridvolume" name="volume"><string name="filename" '
                      'value="nope.vol"/></volume>'), 3, "grid file 'nope.vol' not found"),
    "not a grid": (('<volume type="gridvolume" name="volume"><string name="filename" '
                    'value="junk.vol"/></volume>'), 3,
                   ("cannot load grid file 'junk.vol' (JUNK): not a Mitsuba volume grid (.vol) "
                    "file: 11 bytes, shorter than the 48-byte header")),
    "two channels": (('<volume type="gridvolume" name="volume"><string name="filename" '
                      'value="two.vol"/></volume>'), 3,
                     "the grid has 2 channels; a volume texture reads 1 or 3"),
    "no volume": ("", 2, "texture 'volume' takes 1 nested <volume>, got 0"),
    "wrap mode": (('<volume type="gridvolume" name="volume"><string name="filename" '
                   'value="two.vol"/><string name="wrap_mode" value="zigzag"/></volume>'), 3,
                  "'wrap_mode' of volume 'gridvolume' is 'zigzag'; accepted: repeat, mirror"),
    "unknown": ('<volume type="foovolume" name="volume"/>', 3,
                "unknown volume plugin 'foovolume'; accepted: gridvolume, constvolume"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_is_an_error_at_its_line(tmp_path, case):
    write_vol(tmp_path / "two.vol", np.zeros((2, 2, 2, 2), f32))
    (tmp_path / "junk.vol").write_bytes(b"hello world")
    inner, line, message = BAD[case]
    path = tmp_path / "s.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="sphere"><bsdf type="diffuse">'
                    f'<texture type="volume" name="reflectance">\n{inner}\n</texture></bsdf>'
                    '</shape></scene>')
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    text = str(exc.value)
    assert text.startswith(f"{path}:{line}:"), text
    assert message.replace("JUNK", str(tmp_path / "junk.vol")) in text, text


def test_a_volume_outside_a_texture_is_an_error(tmp_path):
    path = tmp_path / "s.xml"
    path.write_text('<scene version="3.0.0">\n<volume type="constvolume"/>\n</scene>')
    with pytest.raises(SceneError, match=r'<volume> cannot appear directly inside <scene>; '
                       r'nest it inside <texture type="volume">'):
        load_scene_description(path)
