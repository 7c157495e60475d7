"""Textures nested in textures: a checkerboard's `color0`/`color1` set by a bitmap or another
checkerboard, to any depth, as Mitsuba 3 takes them (both are textures there), in rgb and
spectral, as a colour (`eval`) and as one value (`eval_1`: a roughness, a mask's opacity).

Mitsuba evaluates a nested texture at the same surface point as the outer one: the nested
texture's own `to_uv` applies to the surface's uv, not composed with the outer's.  Each scene
here gives each texture a different `to_uv`, so a wrong composition shows.

The scenes: a unit rectangle filling the view of a camera straight above it (the layout of
tests/test_textured_params.py), whose texture regions fall on whole pixels.  Lit by a point
light alone (`sharp`), a pixel's estimate varies only with where in the pixel its samples
fall, so rdsl and Mitsuba 3 agree to a small tolerance block by block; under a constant
emitter (a colour seen through a mask) the comparison is noise-aware: rdsl's RMSE against a
high-spp Mitsuba render must be close to Mitsuba's own at the same spp.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from _mitsuba_render import block_error, mitsuba_variant
from rdsl.runtime.render.image import write_exr
from rdsl.runtime.render.renderer import load_scene

FOV = 2 * math.degrees(math.atan(1 / 4))  # the rectangle [-1, 1]^2 fills the view from z = 4
RES = 16
POINT = ('<emitter type="point"><point name="position" x="0.7" y="0.4" z="1.2"/>'
         '<rgb name="intensity" value="5"/></emitter>')
CONSTANT = '<emitter type="constant"><rgb name="radiance" value="1"/></emitter>'


def scene_xml(shape: str, emitter: str, spp: int = 4) -> str:
    return f"""<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="3"/></integrator>
  <sensor type="perspective"><float name="fov" value="{FOV}"/>
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{RES}"/>
      <integer name="height" value="{RES}"/><rfilter type="box"/></film></sensor>
  <shape type="rectangle">{shape}</shape>
  {emitter}
</scene>"""


def uv(sx: float, sy: float) -> str:
    return f'<transform name="to_uv"><scale x="{sx}" y="{sy}"/></transform>'


def checker(name: str, c0: str, c1: str, to_uv: str = "") -> str:
    """A checkerboard; a colour is a nested texture's XML or an `<rgb>`/`<float>` value."""
    def colour(which: str, c: str) -> str:
        if c.startswith("<"):
            return c.replace('name="?"', f'name="{which}"')
        return f'<rgb name="{which}" value="{c}"/>'
    return (f'<texture type="checkerboard" name="{name}">{to_uv}{colour("color0", c0)}'
            f'{colour("color1", c1)}</texture>')


def bitmap(tmp_path: Path, name: str = "?", to_uv: str = "", raw: bool = False,
           png: bool = False) -> str:
    """A 4x4 image of random colours looked up with nearest filtering (its texels fall on
    whole pixels unless ``to_uv`` scales it)."""
    rng = np.random.default_rng(3)
    texels = rng.uniform(0.05, 0.95, (4, 4, 3)).astype(np.float32)
    if png:
        from PIL import Image

        path = tmp_path / "tex.png"
        Image.fromarray((texels * 255).astype(np.uint8)).save(path)
    else:
        path = tmp_path / "tex.exr"
        write_exr(path, texels)
    return (f'<texture type="bitmap" name="{name}"><string name="filename" value="{path}"/>'
            f'<string name="filter_type" value="nearest"/>{to_uv}'
            + ('<boolean name="raw" value="true"/>' if raw else "") + "</texture>")


def diffuse(texture: str) -> str:
    return f'<bsdf type="diffuse">{texture}</bsdf>'


def rough(texture: str) -> str:
    return f'<bsdf type="roughconductor"><string name="material" value="Au"/>{texture}</bsdf>'


def mask(texture: str) -> str:
    return (f'<bsdf type="mask">{texture}<bsdf type="diffuse">'
            '<rgb name="reflectance" value="0.2, 0.3, 0.8"/></bsdf></bsdf>')


def checker_in_checker(tmp_path: Path) -> str:
    inner = checker("?", "0.9, 0.1, 0.1", "0.1, 0.8, 0.2", uv(4, 2))
    return diffuse(checker("reflectance", inner, "0.2, 0.3, 0.9", uv(2, 2)))


def bitmap_in_checker(tmp_path: Path) -> str:
    """Three levels: a PNG bitmap, and a checkerboard holding an EXR bitmap."""
    inner = checker("?", "0.9, 0.1, 0.1", bitmap(tmp_path), uv(4, 2))
    return diffuse(checker("reflectance", bitmap(tmp_path, png=True, to_uv=uv(1, 1)), inner,
                           uv(2, 2)))


def nested_roughness(tmp_path: Path) -> str:
    """A Float parameter (eval_1) from three levels; bitmaps raw, as Mitsuba's spectral
    variants take a bitmap's one value only from a raw one."""
    inner = checker("?", "0.3, 0.4, 0.2", '<float name="?" value="0.6"/>', uv(4, 2))
    return rough(checker("alpha", bitmap(tmp_path, raw=True), inner, uv(2, 2)))


def nested_opacity(tmp_path: Path) -> str:
    inner = checker("?", "0.9, 0.1, 0.4", '<float name="?" value="0.1"/>', uv(4, 2))
    return mask(checker("opacity", bitmap(tmp_path, raw=True), inner, uv(2, 2)))


def volume_in_checker(tmp_path: Path) -> str:
    """A 4x4x1 grid over the rectangle, looked up at the surface point (no uv)."""
    from rdsl.runtime.scene.volgrid import write_vol

    rng = np.random.default_rng(5)
    write_vol(tmp_path / "grid.vol", rng.uniform(0.05, 0.95, (1, 4, 4, 3)).astype(np.float32))
    volume = (f'<texture type="volume" name="?"><volume type="gridvolume" name="volume">'
              f'<string name="filename" value="{tmp_path / "grid.vol"}"/>'
              '<string name="filter_type" value="nearest"/><transform name="to_world">'
              '<scale x="2" y="2" z="1"/><translate x="-1" y="-1" z="-0.5"/></transform>'
              '</volume></texture>')
    return diffuse(checker("reflectance", "0.9, 0.1, 0.1", volume, uv(2, 2)))


def deep_chain(tmp_path: Path) -> str:
    """Five checkerboards, each the `color1` of the one before, every one of its own scale
    (the finest cells still whole pixels)."""
    colours = ["0.9, 0.1, 0.1", "0.1, 0.8, 0.2", "0.2, 0.3, 0.9", "0.7, 0.7, 0.1",
               "0.1, 0.6, 0.7"]
    tex = '<rgb name="?" value="0.5, 0.5, 0.5"/>'
    for k, c in reversed(list(enumerate(colours))):
        scale = uv(2 ** (k % 4), 2 ** (3 - k % 4))
        tex = checker("reflectance" if k == 0 else "?", c, tex, scale)
    return diffuse(tex)


def emitted(tmp_path: Path) -> str:
    """Emitted light (an area emitter's radiance) from a checkerboard holding a bitmap and a
    checkerboard (Mitsuba takes their colours as reflectances, in [0, 1], without D65 in
    spectral builds: tests/test_spectral_emitter_textures.py)."""
    inner = checker("?", "0.9, 0.1, 0.1", "0.5, 0.8, 0.2", uv(4, 2))
    tex = checker("radiance", bitmap(tmp_path, to_uv=uv(2, 1)), inner, uv(2, 2))
    return f'<emitter type="area">{tex}</emitter>'


SHARP = {"checker_in_checker": checker_in_checker, "bitmap_in_checker": bitmap_in_checker,
         "volume_in_checker": volume_in_checker, "nested_roughness": nested_roughness,
         "deep_chain": deep_chain, "emitted": emitted}


def render_pair(path: Path, variant: str, spp: int) -> tuple[np.ndarray, np.ndarray]:
    """(rdsl's image, Mitsuba's) at ``spp``."""
    with mitsuba_variant(f"scalar_{variant}") as mi:
        theirs = np.array(mi.render(mi.load_file(str(path)), spp=spp, seed=1))[..., :3]
    ours = load_scene(path, variant=variant).render(spp=spp, seed=2)[..., :3]
    return np.asarray(ours, np.float64), theirs.astype(np.float64)


CASES = [(name, variant) for name in SHARP for variant in ("rgb", "spectral")]


@pytest.mark.parametrize(("name", "variant"), CASES)
def test_nested_textures_render_as_mitsuba(tmp_path, name, variant):
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(SHARP[name](tmp_path), POINT))
    # spectral renders have the noise of their sampled wavelengths: more spp
    ours, theirs = render_pair(path, variant, spp=16 if variant == "rgb" else 256)
    assert theirs.max() > 0.05
    err = block_error(ours, theirs, b=4)
    assert err < 0.05, (name, variant, err)


@pytest.mark.parametrize("variant", ["rgb", "spectral"])
def test_nested_opacity_is_mitsubas_within_noise(tmp_path, variant):
    """A mask's opacity (eval_1) from nested textures, seen against a constant emitter:
    rdsl's RMSE against Mitsuba at 16x the spp is about Mitsuba's own at the same spp."""
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(nested_opacity(tmp_path), CONSTANT))
    with mitsuba_variant(f"scalar_{variant}") as mi:
        ref = np.array(mi.render(mi.load_file(str(path)), spp=1024, seed=7))[..., :3]
    ours, theirs = render_pair(path, variant, spp=64)

    def rmse(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a - ref) ** 2)))

    assert rmse(ours) < 1.2 * rmse(theirs), (rmse(ours), rmse(theirs))


def test_generic_build_renders_nesting_as_the_specialized_one(tmp_path):
    """`--no-specialize` reads the nested textures' parameters from its buffer: the same
    image, sample for sample."""
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(nested_roughness(tmp_path), POINT))
    a = load_scene(path).render(seed=3)
    b = load_scene(path, specialize=False).render(seed=3)
    np.testing.assert_array_equal(a, b)


def test_mesh_attribute_in_checker_against_mitsuba(tmp_path):
    """A PLY mesh's vertex colours as a checkerboard's colour: the attribute's values are
    stored for the meshes whose BSDF reads it through the checkerboard."""
    from _plugin_scenes import median_rmse, write_scene
    from test_mesh_attribute import ply_shape, texture, write_ply

    write_ply(tmp_path / "grid.ply")
    tex = checker("reflectance", texture("vertex_color", "?"), "0.2, 0.3, 0.9", uv(2, 2))
    mine, theirs = median_rmse(write_scene(tmp_path, ply_shape(diffuse(tex))), 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


HALVE = """texture halve {
    param base: Texture = 0.5;
    fn eval(si: Surface) -> Spectrum { return base(si) * 0.5; }
    fn eval_1(si: Surface) -> Float { return 0.25; }
}
"""


def test_textures_of_a_users_texture(tmp_path):
    """A user's texture plugin with a `Texture` param set by a nested checkerboard, itself
    nested in a checkerboard, renders as the flat checkerboards of halved colours (halving
    is exact in rgb: the same image, sample for sample)."""
    (tmp_path / "halve.rdsl").write_text(HALVE)
    inner = checker("base", "0.9, 0.1, 0.1", "0.1, 0.8, 0.2", uv(4, 2))
    nested = checker("reflectance", f'<texture type="halve" name="?">{inner}</texture>',
                     "0.2, 0.3, 0.9", uv(2, 2))
    flat_inner = checker("?", "0.45, 0.05, 0.05", "0.05, 0.4, 0.1", uv(4, 2))
    flat = checker("reflectance", flat_inner, "0.2, 0.3, 0.9", uv(2, 2))
    images = []
    for name, tex in (("nested.xml", nested), ("flat.xml", flat)):
        path = tmp_path / name
        path.write_text(scene_xml(diffuse(tex), POINT))
        images.append(load_scene(path).render(seed=3))
    assert images[1].max() > 0.05
    np.testing.assert_array_equal(*images)


NOT_EVAL_1 = """texture plain {
    param c: Texture = 0.5;
    fn eval(si: Surface) -> Spectrum { return c(si); }
}
"""
CYCLE = ('<texture type="checkerboard" id="a"><ref name="color0" id="b"/></texture>\n'
         '<texture type="checkerboard" id="b">\n<ref name="color1" id="a"/></texture>')
BAD = {
    # a <ref> loop through two checkerboards, and one through itself: at the closing <ref>
    "cycle": ('<bsdf type="diffuse"><ref name="reflectance" id="a"/></bsdf>', CYCLE,
              'reference cycle texture \'a\' -> texture \'b\' -> texture \'a\'',
              '<ref name="color1" id="a"/>'),
    "self": ('<bsdf type="diffuse"><ref name="reflectance" id="a"/></bsdf>',
             '<texture type="checkerboard" id="a">\n<ref name="color0" id="a"/></texture>',
             "reference cycle texture 'a' -> texture 'a'", '<ref name="color0" id="a"/>'),
    # not a texture
    "bsdf": (diffuse('<texture type="checkerboard" name="reflectance">\n'
                     '<bsdf type="diffuse" name="color0"/></texture>'), "",
             "parameter 'color0' of texture 'checkerboard' expects a color", 'name="color0"/>'),
    # a nested texture that has no one value, where the checkerboard sets a roughness
    "no_eval_1": (rough('<texture type="checkerboard" name="alpha">\n'
                        '<texture type="plain" name="color0"/></texture>'), "",
                  "texture `plain`", '<texture type="plain"'),
    # a kind that cannot be nested where the checkerboard sets emitted light
    "emitted": (('<emitter type="area"><texture type="checkerboard" name="radiance">\n'
                '<texture type="mesh_attribute" name="color0"><string name="name" '
                'value="vertex_color"/></texture></texture></emitter>'), "",
                "a mesh_attribute texture cannot set emitted light",
                '<texture type="mesh_attribute"'),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_nesting_is_one_clear_error_at_its_line(tmp_path, case):
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.scene import SceneError

    shape, extra, message, marker = BAD[case]
    (tmp_path / "plain.rdsl").write_text(NOT_EVAL_1)
    xml = scene_xml(shape, POINT + extra)
    line = next(k for k, text in enumerate(xml.splitlines(), 1) if marker in text)
    path = tmp_path / "scene.xml"
    path.write_text(xml)
    with pytest.raises((SceneError, CompileError)) as exc:
        load_scene(path).render(seed=0)
    text = str(exc.value)
    assert message in text and text.startswith(f"{path}:{line}:"), text


def test_load_dict_nests_as_the_xml(tmp_path):
    """Mitsuba's dict form of a checkerboard in a checkerboard (a nested dict, and a `ref`)
    renders as the same scene's XML, sample for sample."""
    import rdsl

    T = rdsl.Transform4f
    path = tmp_path / "scene.xml"
    inner_xml = checker("?", "0.9, 0.1, 0.1", "0.1, 0.8, 0.2", uv(4, 2))
    path.write_text(scene_xml(diffuse(checker("reflectance", inner_xml, "0.2, 0.3, 0.9",
                                              uv(2, 2))), POINT))
    inner = {"type": "checkerboard", "id": "inner", "to_uv": T().scale([4, 2, 1]),
             "color0": {"type": "rgb", "value": [0.9, 0.1, 0.1]},
             "color1": {"type": "rgb", "value": [0.1, 0.8, 0.2]}}
    scene = {
        "type": "scene", "inner": inner,
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": FOV,
                   "to_world": T.look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": 4},
                   "film": {"type": "hdrfilm", "width": RES, "height": RES,
                            "rfilter": {"type": "box"}}},
        "shape": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {
            "type": "checkerboard", "to_uv": T().scale([2, 2, 1]),
            "color0": {"type": "ref", "id": "inner"},
            "color1": {"type": "rgb", "value": [0.2, 0.3, 0.9]}}}},
        "light": {"type": "point", "position": [0.7, 0.4, 1.2],
                  "intensity": {"type": "rgb", "value": [5, 5, 5]}},
    }
    a = rdsl.load_dict(scene).render(seed=3)
    b = load_scene(path).render(seed=3)
    assert b.max() > 0.05
    np.testing.assert_array_equal(a, b)


def test_texture_table_refuses_a_cycle_it_is_given():
    """The loader rejects `<ref>` cycles; objects built another way that contain themselves
    get an error from the texture table too, not endless recursion."""
    from types import SimpleNamespace

    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.textures import TextureTable

    def board(ident: str) -> SimpleNamespace:
        grey = SimpleNamespace(rgb=(0.5, 0.5, 0.5), samples=None)
        return SimpleNamespace(category="texture", type="checkerboard", id=ident, loc=None,
                               decl=None, children=[],
                               params={"to_uv": np.eye(4), "color0": grey, "color1": grey})

    a, b = board("a"), board("b")
    a.params["color0"], b.params["color1"] = b, a
    with pytest.raises(CompileError, match="texture `a` contains itself"):
        TextureTable().ref(a, "diffuse.reflectance")
