"""Textures: the rdsl bitmap and checkerboard kernels against numpy references, the scene
dispatch of texture-valued BSDF parameters, image loading, and textured scenes rendered."""

from __future__ import annotations

import numpy as np
import pytest

import rdsl
from rdsl.compiler.sources import STDLIB
from rdsl.core.scene_spec import Instance, SceneSpec, TextureRef
from rdsl.runtime.render.textures import BITMAP_WRAPS, load_bitmap, srgb_to_linear

WRAPS = list(BITMAP_WRAPS)


@pytest.fixture(scope="module")
def bitmap():
    return rdsl.jit(STDLIB / "texture" / "bitmap.rdsl", target="host")


def drjit_wrap(i: np.ndarray, n: int, mode: str) -> np.ndarray:
    """Dr.Jit's Texture::wrap, transcribed (truncating division, as C++)."""
    i = np.asarray(i, np.int64)
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    shifted = np.where(i < 0, i + 1, i)
    div = np.trunc(shifted / n).astype(np.int64)
    mod = i - div * n
    mod = np.where(mod < 0, mod + n, mod)
    if mode == "mirror":
        mod = np.where(((div & 1) == 0) ^ (i < 0), mod, n - 1 - mod)
    return mod


def reference_lookup(tex: np.ndarray, uv: np.ndarray, nearest: bool, mode: str) -> np.ndarray:
    """Dr.Jit's nearest / bilinear texture lookup (texel centres at half-integers)."""
    h, w = tex.shape[:2]
    res = np.array([w, h], np.float32)
    at = lambda x, y: tex[drjit_wrap(y, h, mode), drjit_wrap(x, w, mode)]
    if nearest:
        q = np.floor(uv.astype(np.float32) * res).astype(np.int64)
        return at(q[:, 0], q[:, 1])
    q = uv.astype(np.float32) * res - np.float32(0.5)
    i = np.floor(q).astype(np.int64)
    f = (q - np.floor(q)).astype(np.float64)
    fx, fy = f[:, :1], f[:, 1:]
    x, y = i[:, 0], i[:, 1]
    top = at(x, y) * (1 - fx) + at(x + 1, y) * fx
    bottom = at(x, y + 1) * (1 - fx) + at(x + 1, y + 1) * fx
    return top * (1 - fy) + bottom * fy


@pytest.mark.parametrize("mode", WRAPS)
def test_wrap_modes_match_drjit(bitmap, mode):
    i = np.arange(-23, 24, dtype=np.int32)
    for n in (1, 4, 5):
        got = bitmap.wrap_texel(i, n, BITMAP_WRAPS[mode])
        np.testing.assert_array_equal(got, drjit_wrap(i, n, mode))


@pytest.mark.parametrize("nearest", [False, True], ids=["bilinear", "nearest"])
@pytest.mark.parametrize("mode", WRAPS)
def test_bitmap_lookup_matches_reference(bitmap, mode, nearest):
    rng = np.random.default_rng(3 + 2 * WRAPS.index(mode) + nearest)
    # two textures in one buffer: the second one is looked up through its offset
    first = rng.random((3, 2, 3)).astype(np.float32)
    tex = rng.random((5, 7, 3)).astype(np.float32)
    T = np.concatenate([first.reshape(-1), tex.reshape(-1)])
    uv = rng.uniform(-1.7, 2.6, (4000, 2)).astype(np.float32)
    got = bitmap.bitmap_lookup(T, first.shape[0] * first.shape[1], 7, 5, int(nearest),
                               BITMAP_WRAPS[mode], uv)
    np.testing.assert_allclose(got, reference_lookup(tex, uv, nearest, mode), rtol=1e-5,
                               atol=1e-5)


def test_bilinear_is_exact_at_texel_centres_and_blends_between(bitmap):
    tex = np.array([[[0, 0, 0], [1, 2, 4]]], np.float32)  # 2 x 1
    uv = np.array([[0.25, 0.5], [0.75, 0.5], [0.5, 0.5], [0.375, 0.5]], np.float32)
    got = bitmap.bitmap_lookup(tex.reshape(-1), 0, 2, 1, 0, BITMAP_WRAPS["clamp"], uv)
    np.testing.assert_allclose(got, [[0, 0, 0], [1, 2, 4], [0.5, 1, 2], [0.25, 0.5, 1]])


def surfaces(uv: np.ndarray) -> dict:
    n = len(uv)
    z = np.zeros((n, 3), np.float32)
    wi = np.tile(np.float32([0, 0, 1]), (n, 1))
    return {"p": z, "n": z, "sh_n": z, "uv": uv.astype(np.float32), "wi": wi,
            "t": np.ones(n, np.float32), "valid": np.ones(n, bool)}


def checker_reference(uv, c0, c1, scale=1.0, offset=(0.0, 0.0)):
    t = uv.astype(np.float64) * scale + np.asarray(offset)
    m = (t - np.floor(t)) > 0.5
    return np.where((m[:, 0] == m[:, 1])[:, None], np.asarray(c0), np.asarray(c1))


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_checkerboard_matches_reference(scale):
    mod = rdsl.jit(STDLIB / "texture" / "checkerboard.rdsl", target="host")
    rng = np.random.default_rng(11)
    # avoid uvs within float rounding of a checker edge
    uv = rng.uniform(-2, 2, (3000, 2))
    t = uv * scale + 0.25
    uv = uv[np.all(np.abs(t * 2 - np.round(t * 2)) > 1e-4, axis=1)]
    c0, c1 = (0.9, 0.5, 0.1), (0.05, 0.2, 0.7)
    got = mod["checkerboard.eval"](surfaces(uv), color0=c0, color1=c1,
                                   to_u=(scale, 0.0, 0.25), to_v=(0.0, scale, 0.25))
    np.testing.assert_allclose(got, checker_reference(uv, c0, c1, scale, (0.25, 0.25)),
                               rtol=1e-6)
    default = mod["checkerboard.eval"](surfaces(np.float32([[0.25, 0.25], [0.75, 0.25]])))
    np.testing.assert_allclose(default, [[0.4] * 3, [0.2] * 3], rtol=1e-6)  # Mitsuba's


SHADE = """
import render.scene;
import bsdf.diffuse;
import texture.checkerboard;
import texture.bitmap;
fn shade(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
fn albedo(id: Int, si: Surface, u2: Vec2, T: [Float]) -> Spectrum {
    return scene_bsdf_sample(id, si, 0.5, u2, T).weight;
}
"""


@pytest.mark.parametrize("target", ["scalar", "host"])
def test_texture_valued_parameters_dispatch(target):
    rng = np.random.default_rng(2)
    tex = rng.random((4, 6, 3)).astype(np.float32)
    checker = Instance("checkerboard", {"color0": (0.8, 0.6, 0.4), "color1": 0.1,
                                        "to_u": (2.0, 0.0, 0.0), "to_v": (0.0, 2.0, 0.0)})
    image = Instance("bitmap", {"offset": 1, "width": 6, "height": 4, "filter": 0,
                                "wrap": BITMAP_WRAPS["mirror"], "to_u": (1.0, 0.0, 0.5),
                                "to_v": (0.0, -1.0, 0.0), "average": 0.5})
    scene = SceneSpec(bsdfs=[Instance("diffuse", {"reflectance": TextureRef(0)}),
                             Instance("diffuse", {"reflectance": TextureRef(1)}),
                             Instance("diffuse", {"reflectance": (0.3, 0.2, 0.1)})],
                      textures=[checker, image])
    mod = rdsl.jit(SHADE, target=target, scene=scene)
    T = np.concatenate([np.zeros(3, np.float32), tex.reshape(-1)])  # texture at offset 1
    n = 600
    uv = rng.uniform(-1, 2, (n, 2)).astype(np.float32)
    ids = rng.integers(0, 3, n).astype(np.int32)
    si = surfaces(uv)
    wo = np.tile(np.float32([0, 0, 1]), (n, 1))
    t = (uv * 2) % 1
    keep = np.all(np.abs(t - 0.5) > 1e-4, axis=1) & np.all(np.minimum(t, 1 - t) > 1e-4, axis=1)
    want = np.where((ids == 0)[:, None], checker_reference(uv, (0.8, 0.6, 0.4), 0.1, 2.0),
                    np.where((ids == 1)[:, None],
                             reference_lookup(tex, np.stack([uv[:, 0] + 0.5, -uv[:, 1]], 1),
                                              False, "mirror"),
                             np.float32([0.3, 0.2, 0.1])))
    got = mod.shade(ids, si, wo, T)
    np.testing.assert_allclose(got[keep], want[keep] / np.pi, rtol=1e-5, atol=1e-6)
    u2 = rng.random((n, 2)).astype(np.float32)
    np.testing.assert_allclose(mod.albedo(ids, si, u2, T)[keep], want[keep], rtol=1e-5,
                               atol=1e-6)


def test_load_bitmap_linearizes_8bit_unless_raw(tmp_path):
    from PIL import Image

    px = np.array([[[0, 128, 255], [64, 32, 200]]], np.uint8)
    Image.fromarray(px, "RGB").save(tmp_path / "a.png")
    Image.fromarray(px[:, :, 0], "L").save(tmp_path / "g.png")
    np.testing.assert_allclose(load_bitmap(tmp_path / "a.png"), srgb_to_linear(px / 255),
                               rtol=1e-6)
    np.testing.assert_allclose(load_bitmap(tmp_path / "a.png", raw=True), px / 255, rtol=1e-6)
    grey = load_bitmap(tmp_path / "g.png")
    assert grey.shape == (1, 2, 3)
    np.testing.assert_allclose(grey[..., 2], srgb_to_linear(px[:, :, 0] / 255), rtol=1e-6)
    # sRGB anchors: 0 -> 0, 1 -> 1, 0.5 -> 0.214
    np.testing.assert_allclose(srgb_to_linear(np.array([0, 0.5, 1.0])), [0, 0.21404, 1],
                               atol=1e-5)


def test_load_bitmap_exr_is_linear(tmp_path):
    from rdsl.runtime.render.image import write_exr

    img = np.random.default_rng(0).random((3, 5, 3)).astype(np.float32) * 4
    write_exr(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(load_bitmap(tmp_path / "a.exr"), img)


# ---- textured scenes, rendered ------------------------------------------------------------
# A diffuse rectangle filling the view under a white constant environment: it sees the
# environment over its whole hemisphere, so every pixel shows the reflectance (plus noise).

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="25"/>
        <transform name="to_world"><lookat origin="0, 0, 3.5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/>
            <rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    </sensor>
    <shape type="rectangle">
        <bsdf type="diffuse">
            {texture}
        </bsdf>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
</scene>
"""
RES = 48
FOV = 25.0


def pixel_uvs(res: int = RES) -> np.ndarray:
    """uv of the textured rectangle at each pixel centre (it fills the view): image right is
    +x, image up is +y, and the rectangle's uv is ((x + 1) / 2, (y + 1) / 2)."""
    s = 3.5 * np.tan(np.radians(FOV / 2))
    c = (np.arange(res) + 0.5) / res * 2 - 1
    x, y = np.meshgrid(c * s, -c * s)
    return np.stack([(x + 1) / 2, (y + 1) / 2], axis=-1)


def render(tmp_path, texture: str, spp: int = 64) -> np.ndarray:
    pytest.importorskip("rdsl.runtime.embree")
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "scene.xml"
    path.write_text(SCENE.format(res=RES, texture=texture))
    scene = load_scene(path, target="host")
    img = scene.render(spp=spp, seed=4)
    assert scene.nonfinite == 0 and img.shape == (RES, RES, 3)
    return img


def test_checkerboard_scene(tmp_path):
    c0, c1 = np.array([0.8, 0.5, 0.2]), np.array([0.1, 0.3, 0.6])
    img = render(tmp_path, f"""<texture type="checkerboard" name="reflectance">
                <rgb name="color0" value="{', '.join(map(str, c0))}"/>
                <rgb name="color1" value="{', '.join(map(str, c1))}"/>
                <transform name="to_uv"><scale x="3" y="3"/></transform>
            </texture>""")
    t = pixel_uvs() * 3
    f = t - np.floor(t)
    # pixels whose footprint (a box filter, ~0.03 in uv) lies inside one checker cell
    inside = np.all(np.minimum(np.abs(f - 0.5), np.minimum(f, 1 - f)) > 0.06, axis=-1)
    first = (f[..., 0] > 0.5) == (f[..., 1] > 0.5)
    a, b = img[inside & first], img[inside & ~first]
    assert len(a) > 100 and len(b) > 100
    np.testing.assert_allclose(a.mean(axis=0), c0, rtol=0.03)
    np.testing.assert_allclose(b.mean(axis=0), c1, rtol=0.03)
    assert np.std(a[:, 0]) / c0[0] < 0.15  # noise, no pattern within a cell


def test_bitmap_scene(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(9)
    px = rng.integers(40, 255, (3, 4, 3)).astype(np.uint8)
    Image.fromarray(px, "RGB").save(tmp_path / "tex.png")
    img = render(tmp_path, """<texture type="bitmap" name="reflectance">
                <string name="filename" value="tex.png"/>
                <string name="filter_type" value="nearest"/>
            </texture>""")
    uv = pixel_uvs()
    q = uv * [4, 3]
    f = q - np.floor(q)
    inside = np.all(np.minimum(f, 1 - f) > 0.08, axis=-1)
    col = np.floor(q[..., 0]).astype(int)
    row = np.floor(q[..., 1]).astype(int)  # v runs down the image's rows, as in Mitsuba
    texels = srgb_to_linear(px / 255.0)
    seen = 0
    for r in range(3):
        for c in range(4):
            sel = inside & (row == r) & (col == c)
            if sel.sum() >= 20:  # every visible texel shows its linearized color
                np.testing.assert_allclose(img[sel].mean(axis=0), texels[r, c], rtol=0.05)
                seen += 1
    assert seen >= 8


def test_missing_texture_file_is_named_with_its_line(tmp_path):
    from rdsl.runtime.render.renderer import load_scene
    from rdsl.runtime.scene import SceneError

    path = tmp_path / "scene.xml"
    path.write_text(SCENE.format(res=8, texture="""<texture type="bitmap" name="reflectance">
                <string name="filename" value="nowhere.png"/>
            </texture>"""))
    line = 1 + next(i for i, s in enumerate(path.read_text().splitlines()) if "nowhere" in s)
    with pytest.raises(SceneError) as e:
        load_scene(path)
    msg = str(e.value)
    assert "nowhere.png" in msg and f"scene.xml:{line}:" in msg, msg
