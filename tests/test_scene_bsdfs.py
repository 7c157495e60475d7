"""Every stdlib BSDF, and the combinators twosided / blendbsdf / mask, used from scenes.

1. one small scene with a sphere of each BSDF renders without NaN/Inf, non-negative, with a
   plausible brightness;
2. delta lobes and MIS: a perfect mirror facing an area light at normal incidence shows the
   light's radiance times the conductor's F(0), exactly (every sample hits the light through
   a delta bounce, whose MIS weight must be 1, and emitter sampling adds nothing);
3. twosided: a diffuse patch whose normal points away from the light and camera is as
   bright as the same patch facing them when wrapped in twosided, black when not;
4. blendbsdf: sample() against pdf() (chi-square) and eval / pdf, through the leaf dispatch;
5. the Mitsuba parameter mapping: distribution strings, anisotropic roughness, parameters
   the rdsl plugin lacks (an error naming them, unless at Mitsuba's default).
"""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.core.scene_spec import Instance, SceneSpec
from rdsl.runtime.render.bsdfs import mixture_params
from rdsl.runtime.render.renderer import load_scene
from test_bsdf_plugins import chi2_directions, pdf_fn, rng, sample, surface, tile, wi_at

f32 = np.float32


def scene_xml(body: str, sensor: str, max_depth: int = 6, res: int = 32) -> str:
    return f"""<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="{max_depth}"/></integrator>
    <sensor type="perspective">
        {sensor}
        <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/><rfilter type="box"/></film>
    </sensor>
    {body}
</scene>"""


def render(tmp_path, xml: str, name: str, spp: int = 4, seed: int = 0):
    path = tmp_path / f"{name}.xml"
    path.write_text(xml)
    scene = load_scene(path)
    img = scene.render(spp=spp, seed=seed)
    return scene, img


OBLIQUE = ('<float name="fov" value="60"/><transform name="to_world">'
           '<lookat origin="0, -9, 7" target="0, 0, 0" up="0, 0, 1"/></transform>')

BSDFS = [
    '<bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.5, 0.2"/></bsdf>',
    '<bsdf type="conductor"><string name="material" value="Au"/></bsdf>',
    '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf>',  # beckmann
    ('<bsdf type="roughconductor"><string name="distribution" value="ggx"/>'
     '<float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.4"/></bsdf>'),
    '<bsdf type="dielectric"/>',
    '<bsdf type="thindielectric"><float name="int_ior" value="1.33"/></bsdf>',
    '<bsdf type="roughdielectric"><float name="alpha" value="0.3"/></bsdf>',
    '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.1, 0.3, 0.6"/></bsdf>',
    ('<bsdf type="roughplastic"><string name="distribution" value="ggx"/>'
     '<boolean name="nonlinear" value="true"/></bsdf>'),
    '<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>',
    '<bsdf type="twosided"><bsdf type="diffuse"/><bsdf type="conductor"/></bsdf>',
    ('<bsdf type="blendbsdf"><float name="weight" value="0.3"/><bsdf type="diffuse"/>'
     '<bsdf type="conductor"/></bsdf>'),
    ('<bsdf type="twosided"><bsdf type="blendbsdf"><float name="weight" value="0.6"/>'
     '<bsdf type="roughconductor"/><bsdf type="plastic"/></bsdf></bsdf>'),
    ('<bsdf type="mask"><float name="opacity" value="0.4"/>'
     '<bsdf type="twosided"><bsdf type="roughconductor"/></bsdf></bsdf>'),
]


def test_every_bsdf_renders(tmp_path):
    spheres = "".join(
        f'<shape type="sphere"><point name="center" value="{2.2 * (i % 5) - 4.4}, '
        f'{2.2 * (i // 5) - 2.2}, 1"/><float name="radius" value="0.9"/>{b}</shape>'
        for i, b in enumerate(BSDFS))
    body = ('<shape type="rectangle"><transform name="to_world"><scale value="4"/>'
            '<translate z="8"/></transform><boolean name="flip_normals" value="true"/>'
            '<emitter type="area"><rgb name="radiance" value="3, 3, 3"/></emitter></shape>'
            '<shape type="rectangle"><transform name="to_world"><scale value="12"/>'
            '</transform><bsdf type="diffuse"/></shape>' + spheres)
    scene, img = render(tmp_path, scene_xml(body, OBLIQUE, res=48), "all", spp=8)
    used = {i.plugin for i in scene.bsdfs} | {c.plugin for i in scene.bsdfs for c in i.children}
    assert used == {"diffuse", "conductor", "roughconductor", "dielectric", "thindielectric",
                    "roughdielectric", "plastic", "roughplastic", "mixture"}
    assert scene.nonfinite == 0
    assert np.all(np.isfinite(img)) and img.min() >= 0
    # the floor receives ~ L * (solid angle of the light) / pi * 0.5 ~ 0.3 near the middle
    assert 0.05 < img.mean() < 1.0
    # the lower half (floor and spheres) is lit everywhere: no black disk of discarded work
    assert (img[24:].reshape(-1, 3).max(axis=1) > 0).mean() > 0.95


MIRROR_L = (4.0, 2.0, 1.0)
DOWN = ('<float name="fov" value="8"/><transform name="to_world">'
        '<lookat origin="0, 0, 1" target="0, 0, 0" up="0, 1, 0"/></transform>')


def mirror_body(bsdf: str, flip: bool = False) -> str:
    """A mirror at z = 0 facing up (or down, flipped), a 1 x 1 light at z = 2 facing down."""
    return ('<shape type="rectangle"><transform name="to_world"><scale value="0.5"/>'
            '<translate z="2"/></transform><boolean name="flip_normals" value="true"/>'
            '<emitter type="area"><rgb name="radiance" value="'
            + ", ".join(map(str, MIRROR_L)) + '"/></emitter></shape>'
            '<shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>'
            f'<boolean name="flip_normals" value="{str(flip).lower()}"/>{bsdf}</shape>')


def test_mirror_delta_mis(tmp_path):
    """L * R * F(0) exactly: with the light's pdf (4 / area = 4 per sr) comparable to the
    discrete pdf 1, treating the delta bounce as an ordinary sample would darken it 17x."""
    eta, k, r = np.array([0.2, 0.5, 1.4]), np.array([3.9, 2.4, 1.6]), 0.8
    bsdf = ('<bsdf type="conductor"><rgb name="eta" value="0.2, 0.5, 1.4"/>'
            '<rgb name="k" value="3.9, 2.4, 1.6"/>'
            f'<float name="specular_reflectance" value="{r}"/></bsdf>')
    f0 = ((eta - 1) ** 2 + k ** 2) / ((eta + 1) ** 2 + k ** 2)
    expected = np.array(MIRROR_L) * r * f0
    for name, xml in [("mirror", scene_xml(mirror_body(bsdf), DOWN, 2, 8)),
                      # seen from below: a twosided mirror is the same mirror
                      ("mirror2", scene_xml(mirror_body(f'<bsdf type="twosided">{bsdf}</bsdf>',
                                                        flip=True), DOWN, 2, 8))]:
        scene, img = render(tmp_path, xml, name, spp=16)
        assert scene.nonfinite == 0
        np.testing.assert_allclose(img.reshape(-1, 3), np.tile(expected, (64, 1)), rtol=1e-3,
                                   err_msg=name)
    # more bounces: light -> (default diffuse back of the light) adds light, never removes it
    _, img = render(tmp_path, scene_xml(mirror_body(bsdf), DOWN, 6, 8), "mirror6", spp=16)
    assert np.all(img.reshape(-1, 3) >= expected * (1 - 1e-3))


def patches(right_bsdf: str) -> str:
    """Two diffuse patches mirror-symmetric about x = 0: the left one faces up, the right one
    faces down (flipped normals) with `right_bsdf`; a light above between them."""
    return ('<shape type="rectangle"><transform name="to_world"><scale value="1"/>'
            '<translate z="3"/></transform><boolean name="flip_normals" value="true"/>'
            '<emitter type="area"><rgb name="radiance" value="5, 5, 5"/></emitter></shape>'
            '<shape type="rectangle"><transform name="to_world"><scale value="1.4"/>'
            '<translate x="-1.5"/></transform><bsdf type="diffuse"/></shape>'
            '<shape type="rectangle"><transform name="to_world"><scale value="1.4"/>'
            '<translate x="1.5"/></transform><boolean name="flip_normals" value="true"/>'
            f'{right_bsdf}</shape>')


def test_twosided(tmp_path):
    cam = ('<float name="fov" value="70"/><transform name="to_world">'
           '<lookat origin="0, -1, 6" target="0, 0, 0" up="0, 1, 0"/></transform>')
    _, img = render(tmp_path, scene_xml(patches('<bsdf type="twosided"><bsdf type="diffuse"/>'
                                                '</bsdf>'), cam, 4), "two", spp=16)
    left, right = img[:, :16].mean(), img[:, 16:][:, ::-1].mean()
    assert left > 0.005  # the light hides the middle: patches are a thin U
    assert right == pytest.approx(left, rel=0.05)
    _, img = render(tmp_path, scene_xml(patches('<bsdf type="diffuse"/>'), cam, 4), "one",
                    spp=16)
    left1, right1 = img[:, :16].mean(), img[:, 16:][:, ::-1].mean()
    assert left1 == pytest.approx(left, rel=0.05)
    assert right1 < 0.05 * left  # the back of a one-sided BSDF is black


# ---------------------------------------------------------------------------- blendbsdf

BLEND_SRC = """import render.scene;
import bsdf.mixture;
import bsdf.diffuse;
import bsdf.roughconductor;
import bsdf.plastic;

fn blend.sample(id: Int, si: Surface, u1: Float, u2: Vec2, T: [Float]) -> BsdfSample {
    return scene_bsdf_sample(id, si, u1, u2, T);
}
fn blend.eval(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
fn blend.pdf(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Float {
    return scene_bsdf_pdf(id, si, wo, T);
}
"""


class Blend:
    """The scene's BSDF `id` (a blendbsdf through the scene dispatch) as a plugin module."""

    def __init__(self, mod, ident: int) -> None:
        self.mod, self.ident = mod, ident

    def __getitem__(self, name: str):
        k = self.mod[name.replace(".", "_")]
        return lambda *args, **_: k(np.full(len(args[0]["wi"]), self.ident, np.int32), *args,
                                    np.zeros(3, f32))


@pytest.fixture(scope="module")
def blend():
    src = BLEND_SRC.replace("blend.", "blend_")
    leaves = [Instance("diffuse", {"reflectance": 0.7}),
              Instance("roughconductor", {"alpha": 0.2, "distribution": 1}),
              Instance("plastic", {"diffuse_reflectance": 0.6})]
    mix = [Instance("mixture", mixture_params([(a, 0.65, 0.65, False), (1, 0.35, 0.35, False)]))
           for a in (0, 2)]
    return rdsl.jit(src, target="host", scene=SceneSpec(bsdfs=mix, bsdf_leaves=leaves))


@pytest.mark.parametrize("a,theta", [(0, 0.4), (0, 1.3), (2, 0.8)])
def test_blendbsdf_chi2(blend, a, theta):
    """blendbsdf(diffuse or plastic, beckmann roughconductor), weight 0.35."""
    mod, params = Blend(blend, a // 2), {}
    n = 300_000
    wi = wi_at(theta)
    _, bs = sample(mod, "blend", wi, n, rng("blend", a, theta))
    delta = bs["delta"].astype(bool)
    valid = (bs["pdf"] > 0) & ~delta
    obs, prob = [], []
    if a == 2:  # plastic's specular lobe: chosen with (1 - weight) * its own probability
        assert np.all(bs["wo"][delta] == np.array([-wi[0], -wi[1], wi[2]], f32))
        obs, prob = [delta.sum()], [float(bs["pdf"][delta][0])]
    p = chi2_directions(bs["wo"], valid, pdf_fn(mod, "blend", wi, **params), n,
                        delta_obs=obs, delta_prob=prob, lower=False)
    assert p > 1e-3
    # a smooth sample's weight is eval / pdf of the whole mixture
    si = surface(tile(wi, int(valid.sum())))
    wo = np.ascontiguousarray(bs["wo"][valid])
    f = np.asarray(mod["blend.eval"](si, wo)).reshape(len(wo), -1)
    pdf = np.asarray(mod["blend.pdf"](si, wo))
    np.testing.assert_allclose(bs["pdf"][valid], pdf, rtol=1e-4)
    np.testing.assert_allclose(bs["weight"][valid], f / pdf[:, None], rtol=2e-3, atol=1e-6)


# ---------------------------------------------------------------------------- mapping

def load_bsdf(tmp_path, bsdf: str):
    body = ('<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/>'
            f'</emitter></shape><shape type="cube">{bsdf}</shape>')
    path = tmp_path / "m.xml"
    path.write_text(scene_xml(body, OBLIQUE))
    return load_scene(path).bsdfs[-1]


def test_parameter_mapping(tmp_path):
    inst = load_bsdf(tmp_path, '<bsdf type="roughconductor"><float name="alpha" value="0.3"/>'
                     '</bsdf>')
    assert inst.params["distribution"] == 1  # Mitsuba's default: beckmann
    # isotropic: `alpha` alone, the plugin's alpha_v (default -1) follows it
    assert inst.params["alpha"] == 0.3 and "alpha_v" not in inst.params
    inst = load_bsdf(tmp_path, '<bsdf type="roughdielectric"><string name="distribution" '
                     'value="ggx"/><float name="int_ior" value="1.33"/></bsdf>')
    assert inst.params["distribution"] == 0 and inst.params["int_ior"] == 1.33
    assert "eta" not in inst.params  # derived from the IORs by the loader
    inst = load_bsdf(tmp_path, '<bsdf type="roughdielectric"><float name="alpha_u" '
                     'value="0.1"/><float name="alpha_v" value="0.3"/></bsdf>')
    assert inst.params["alpha"] == 0.1 and inst.params["alpha_v"] == 0.3  # Mitsuba's u, v
    inst = load_bsdf(tmp_path, '<bsdf type="plastic"><boolean name="nonlinear" value="true"/>'
                     '</bsdf>')
    assert inst.params["nonlinear"] is True
    # sampling all normals instead of the visible ones converges to the same image: accepted
    # (tests/compat renders it against Mitsuba)
    load_bsdf(tmp_path, '<bsdf type="roughplastic"><boolean name="sample_visible" '
              'value="false"/></bsdf>')


@pytest.mark.parametrize("bsdf,words", [
    (('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
      '<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
      '<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
      '<bsdf type="mask"><bsdf type="blendbsdf"><float name="weight" value="0.5"/>'
      '<bsdf type="diffuse"/><bsdf type="diffuse"/></bsdf></bsdf></bsdf></bsdf></bsdf>'),
     "nest 5 BSDFs"),
    (('<bsdf type="blendbsdf"><float name="weight" value="0.5"/><bsdf type="diffuse"/>'
      '<bsdf type="twosided"><bsdf type="mask"><bsdf type="roughdielectric"/></bsdf></bsdf>'
      '</bsdf>'), "transmission"),
    ('<bsdf type="twosided"><bsdf type="dielectric"/></bsdf>', "transmission"),
])
def test_mapping_errors(tmp_path, bsdf, words):
    with pytest.raises(CompileError, match=words):
        load_bsdf(tmp_path, bsdf)
