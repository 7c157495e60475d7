"""User plugins written from docs/plugins.md alone (tests/plugin_walk/), checked against
independent truth: a user Lambert BSDF in a white furnace (albedo 1 reflects the constant
environment's 1), each param kind a scene sets reaching a texture (its value a closed form of
them, read back as the `aov` integrator's albedo), a user direct-lighting integrator against
the stdlib's `direct` under a point light (where BSDF sampling adds nothing), a user wrapper
integrator around it (its nested estimate times 4, sample for sample), and forward-mode
derivatives by a user BSDF's param against central differences."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rdsl

PLUGINS = Path(__file__).resolve().parent / "plugin_walk"

CAMERA = """
    <sensor type="{camera}">
        {fov}
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/><rfilter type="box"/></film>
    </sensor>"""


def write(folder: Path, body: str, camera: str = "perspective", res: int = 16,
          spp: int = 16) -> Path:
    """A scene of ``body`` and a camera on the z axis, next to nothing: its plugins come from
    tests/plugin_walk/ through ``plugins=``."""
    fov = '<float name="fov" value="30"/>' if camera == "perspective" else ""
    path = folder / "scene.xml"
    path.write_text('<scene version="3.0.0">' + CAMERA.format(camera=camera, fov=fov, res=res,
                                                              spp=spp) + body + "</scene>\n")
    return path


def load(path: Path, **kw) -> rdsl.Scene:
    return rdsl.load_scene(path, plugins=[PLUGINS], **kw)


@pytest.mark.parametrize("variant", ["rgb", "mono", "spectral"])
def test_user_lambert_white_furnace(tmp_path, variant):
    """Albedo 0.5 x 2 x 1 on a sphere in a constant environment of radiance 1: every pixel
    is 1 in expectation (the sphere's or the environment's)."""
    path = write(tmp_path, """
    <integrator type="path"><integer name="max_depth" value="-1"/></integrator>
    <emitter type="constant"><float name="radiance" value="1"/></emitter>
    <shape type="sphere"><bsdf type="tintlambert"><float name="reflectance" value="0.5"/>
        <float name="tint" value="2"/></bsdf></shape>""", spp=64)
    img = load(path, variant=variant).render(seed=0)
    sphere = img[6:10, 6:10]
    assert abs(sphere.mean() - 1.0) < 0.02, sphere.mean()
    assert abs(img.mean() - 1.0) < 0.01, img.mean()
    if variant != "spectral":  # (spectral: the noise of four wavelengths a sample)
        np.testing.assert_allclose(img[0, 0], 1.0, atol=1e-6)  # the environment itself


KINDS = """
    <integrator type="aov"><string name="aovs" value="a:albedo"/></integrator>
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><texture type="kinds" name="reflectance">
            <float name="f" value="{f}"/><integer name="i" value="{i}"/>
            <integer name="u" value="7"/><boolean name="b" value="{b}"/>
            <spectrum name="s" value="{s}"/>
            <texture type="checkerboard" name="t"><float name="color0" value="0.05"/>
                <float name="color1" value="0.05"/></texture>
            <vector name="v" x="0.0" y="{vy}" z="0.0"/>
        </texture></bsdf></shape>"""


@pytest.mark.parametrize("variant,specialize", [("rgb", True), ("rgb", False),
                                                ("mono", True)])
@pytest.mark.parametrize("f,i,b,s,vy", [(0.2, 3, False, 0.5, 0.1), (0.1, -4, True, 0.3, 0.0)])
def test_every_param_kind_reaches_the_plugin(tmp_path, variant, specialize, f, i, b, s, vy):
    path = write(tmp_path, KINDS.format(f=f, i=i, b=str(b).lower(), s=s, vy=vy),
                 camera="orthographic", res=4, spp=1)
    scene = load(path, variant=variant, specialize=specialize)
    img = scene.render(seed=0)
    assert scene.channel_names[-3:] == ["a.R", "a.G", "a.B"]
    want = s * (f + i * 0.01 + 7 * 0.001 + vy + (1.0 if b else 0.0)) + 0.05
    np.testing.assert_allclose(img[..., -3:], want, rtol=2e-6)


POINT_LIT = """
    <integrator type="{integrator}"/>
    <emitter type="point"><point name="position" x="1" y="3" z="3"/>
        <rgb name="intensity" value="10, 8, 6"/></emitter>
    <shape type="sphere"><bsdf type="tintlambert"><rgb name="tint" value="1, 0.5, 0.25"/>
    </bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/>
        <scale value="4"/><translate y="-1"/></transform><bsdf type="diffuse"/></shape>"""


def test_user_direct_integrator_matches_the_stdlibs_and_its_wrapper(tmp_path):
    """Under a point light the stdlib's `direct` is its emitter sample (a BSDF sample never
    hits a delta light), drawn from the sampler's first numbers as `mydirect` draws it; the
    wrapper `exposure` (stops 2) gives 4 times its nested integrator's image."""
    mine = load(write(tmp_path, POINT_LIT.format(integrator="mydirect"))).render(seed=3)
    std = load(write(tmp_path, POINT_LIT.format(integrator="direct"))).render(seed=3)
    assert mine.mean() > 0.01
    np.testing.assert_allclose(mine, std, rtol=1e-5, atol=1e-6)
    wrapped = POINT_LIT.format(integrator='exposure"><float name="stops" value="2"/>'
                                          '<integrator type="mydirect"/></integrator><!-- x')
    got = load(write(tmp_path, wrapped.replace("<!-- x\"/>", ""))).render(seed=3)
    np.testing.assert_allclose(got, 4.0 * mine, rtol=1e-6)


def test_forward_derivative_by_a_user_param_matches_central_differences(tmp_path):
    path = write(tmp_path, """
    <integrator type="path"><integer name="max_depth" value="3"/>
        <integer name="rr_depth" value="100"/></integrator>
    <emitter type="constant"><float name="radiance" value="1"/></emitter>
    <shape type="sphere" id="ball"><bsdf type="tintlambert" id="mat">
        <rgb name="tint" value="0.5, 1, 1"/></bsdf></shape>""")
    scene = load(path)
    assert "mat.tint" in scene.params
    img, d_img = scene.render_forward("mat.tint", spp=16, seed=0)
    base, eps = np.array([0.5, 1.0, 1.0]), 1e-3
    scene.params["mat.tint"] = list(base + eps)
    up = scene.render(spp=16, seed=0)
    scene.params["mat.tint"] = list(base - eps)
    down = scene.render(spp=16, seed=0)
    fd = (up - down) / (2 * eps)
    assert np.abs(d_img).max() > 0.1
    np.testing.assert_allclose(d_img, fd, atol=2e-3)
