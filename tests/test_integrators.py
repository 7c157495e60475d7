"""Mitsuba 3's `direct` and `aov` integrators (stdlib/integrator/direct.rdsl, aov.rdsl)."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _scenes import CBOX

embree = pytest.importorskip("rdsl.runtime.embree")

PATH_INTEGRATOR = """<integrator type="path">
        <integer name="max_depth" value="$max_depth"/>
    </integrator>"""

# a 20 x 20 diffuse plane at z = 0 (normal +z), seen from (0, 0, DIST) looking down, under a
# constant environment; box filter, so each pixel's AOVs are its samples' mean
DIST = 2.0
FOV = 40.0
NEAR = 0.01
PLANE = """<scene version="3.0.0">
    <integrator type="aov">
        <string name="aovs" value="dd.y:depth,nn:sh_normal,pp:position,gg:geo_normal,aa:albedo"/>
        {nested}
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <float name="near_clip" value="{near}"/>
        <transform name="to_world">
            <lookat origin="0, 0, {dist}" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="1"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="24"/>
            <integer name="height" value="16"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="10"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.25, 0.5, 0.75"/></bsdf>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="1, 1, 1"/></emitter>
</scene>
"""
AOV_NAMES = ["dd.y.T", "nn.X", "nn.Y", "nn.Z", "pp.X", "pp.Y", "pp.Z", "gg.X", "gg.Y", "gg.Z",
             "aa.R", "aa.G", "aa.B"]


def _plane(tmp_path: Path, nested: str = "") -> Path:
    p = tmp_path / "plane.xml"
    p.write_text(PLANE.format(nested=nested, fov=FOV, dist=DIST, near=NEAR))
    return p


@pytest.mark.skipif(not CBOX.is_file(), reason=f"{CBOX} is not present")
def test_direct_matches_path_with_max_depth_2(tmp_path):
    from rdsl.runtime.render.image import rmse
    from rdsl.runtime.render.renderer import load_scene

    text = CBOX.read_text()
    assert PATH_INTEGRATOR in text
    direct = tmp_path / "cbox_direct.xml"
    direct.write_text(text.replace(PATH_INTEGRATOR, '<integrator type="direct"/>'))
    a = load_scene(direct, res=64).render(spp=64, seed=1)
    b = load_scene(CBOX, res=64, max_depth=2).render(spp=64, seed=2)
    b2 = load_scene(CBOX, res=64, max_depth=2).render(spp=64, seed=3)
    # Mitsuba's path with max_depth 2 is direct illumination: the same expected image
    np.testing.assert_allclose(a.mean(axis=(0, 1)), b.mean(axis=(0, 1)), rtol=0.01)
    # their difference is noise: no larger than between two path renders (plus a margin)
    assert rmse(a, b) < 1.5 * rmse(b2, b), (rmse(a, b), rmse(b2, b))


def test_direct_sample_counts_keep_the_expectation(tmp_path):
    from rdsl.runtime.render.renderer import load_scene

    p = tmp_path / "plane.xml"
    base = PLANE.replace('<integrator type="aov">', "<!--").replace("</integrator>", "-->")
    means = []
    for attrs in ("", ('<integer name="emitter_samples" value="3"/>'
                       '<integer name="bsdf_samples" value="2"/>'),
                  '<integer name="shading_samples" value="2"/>',
                  '<integer name="bsdf_samples" value="0"/>',
                  '<integer name="emitter_samples" value="0"/>'):
        p.write_text(base.format(nested="", fov=FOV, dist=DIST, near=NEAR)
                     .replace("<sensor", f'<integrator type="direct">{attrs}</integrator>'
                                         "<sensor"))
        means.append(load_scene(p).render(spp=64, seed=4).mean(axis=(0, 1)))
    # a diffuse plane under a unit constant environment reflects its albedo
    for m in means:
        np.testing.assert_allclose(m, [0.25, 0.5, 0.75], rtol=0.02)


def test_aov_depth_normal_position_albedo(tmp_path):
    from rdsl.runtime.render.renderer import load_scene

    scene = load_scene(_plane(tmp_path))
    assert scene.channel_names == ["R", "G", "B", *AOV_NAMES]
    img = scene.render(spp=1, seed=0)
    assert img.shape == (16, 24, 3 + len(AOV_NAMES))
    ch = {n: img[..., i] for i, n in enumerate(scene.channel_names)}
    # no nested integrator: the radiance channels are 0, as Mitsuba's aov
    assert not img[..., :3].any()
    pos = np.stack([ch["pp.X"], ch["pp.Y"], ch["pp.Z"]], axis=-1)
    np.testing.assert_array_equal(pos[..., 2], 0.0)
    # depth is the hit distance t of the camera ray, which (as in Mitsuba 3) starts on the
    # near plane: |p - camera| minus the near_clip / cos(theta) before it
    dist = np.linalg.norm(pos - np.array([0.0, 0.0, DIST], np.float32), axis=-1)
    depth = dist * (1 - NEAR / DIST)
    np.testing.assert_allclose(ch["dd.y.T"], depth, rtol=1e-5)
    half = math.tan(math.radians(FOV) / 2)  # fov is along x (the larger axis)
    corner = (DIST - NEAR) * math.sqrt(1 + half**2 * (1 + (16 / 24) ** 2))
    assert (DIST - NEAR) * (1 - 1e-6) <= ch["dd.y.T"].min()
    assert ch["dd.y.T"].max() <= corner * 1.00001
    # a camera ray through pixel (x, y) hits the plane where the pinhole model says
    x = (np.arange(24) + 0.5) / 24 * 2 - 1
    np.testing.assert_allclose(pos[8, :, 0], DIST * half * x, atol=DIST * half / 24 + 1e-6)
    for n in ("nn", "gg"):
        np.testing.assert_array_equal(ch[f"{n}.X"], 0.0)
        np.testing.assert_array_equal(ch[f"{n}.Y"], 0.0)
        np.testing.assert_array_equal(ch[f"{n}.Z"], 1.0)
    # Mitsuba's albedo of a diffuse BSDF is its reflectance
    for c, v in zip("RGB", (0.25, 0.5, 0.75)):
        np.testing.assert_allclose(ch[f"aa.{c}"], v, rtol=1e-5)


def test_aov_with_nested_integrator(tmp_path):
    from rdsl.runtime.render.renderer import load_scene

    scene = load_scene(_plane(tmp_path, '<integrator type="direct"/>'))
    img = scene.render(spp=16, seed=0)
    np.testing.assert_allclose(img[..., :3].mean(axis=(0, 1)), [0.25, 0.5, 0.75], rtol=0.02)
    np.testing.assert_array_equal(img[..., scene.channel_names.index("nn.Z")], 1.0)


@pytest.mark.parametrize("attrs, message", [
    ('<integer name="shading_samples" value="2"/><integer name="bsdf_samples" value="1"/>',
     "cannot specify both 'shading_samples'"),
    ('<integer name="emitter_samples" value="0"/><integer name="bsdf_samples" value="0"/>',
     "must have at least 1 BSDF or emitter sample"),
])
def test_direct_sample_count_mistakes(tmp_path, attrs, message):
    from rdsl.runtime.scene import SceneError, load_scene_description

    p = tmp_path / "plane.xml"
    base = PLANE.replace('<integrator type="aov">', "<!--").replace("</integrator>", "-->")
    p.write_text(base.format(nested="", fov=FOV, dist=DIST, near=NEAR)
                 .replace("<sensor", f'<integrator type="direct">{attrs}</integrator><sensor'))
    with pytest.raises(SceneError, match=message):
        load_scene_description(p)


def test_unknown_integrator_is_a_clear_error(tmp_path):
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.renderer import load_scene

    p = _plane(tmp_path)
    p.write_text(p.read_text().replace("dd.y:depth", "dd.y:curvature"))
    with pytest.raises(CompileError, match="curvature"):
        load_scene(p).compile()


def test_cli_writes_aov_channels(tmp_path):
    from rdsl.runtime.render.image import read_exr_channels

    out = tmp_path / "plane.exr"
    r = subprocess.run([sys.executable, "-m", "rdsl.cli", "render",
                        str(_plane(tmp_path)), "--spp", "1", "-o", str(out), "--quiet"],
                       check=False, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    chans = read_exr_channels(out)
    assert set(chans) == {"R", "G", "B", *AOV_NAMES}
    assert out.with_suffix(".png").is_file()
    np.testing.assert_array_equal(chans["nn.Z"], 1.0)


@pytest.mark.skipif(not CBOX.is_file(), reason=f"{CBOX} is not present")
@pytest.mark.parametrize("max_depth", [0, 1])
def test_path_with_max_depth_0_and_1_renders_as_mitsuba(max_depth):
    """max_depth 0: no light at all (specialization leaves the kernel no ray to trace);
    1: only what the camera sees of the emitters.  Both as Mitsuba 3 renders them."""
    from rdsl.runtime.render.renderer import load_scene

    imgs = [load_scene(CBOX, res=32, max_depth=max_depth, specialize=s).render(spp=256, seed=5)
            for s in (True, False)]
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    ref = np.array(mi.render(mi.load_file(str(CBOX), res=32, max_depth=max_depth), spp=256))
    for img in imgs:
        assert np.isfinite(img).all()
        if max_depth == 0:
            assert not ref.any() and not img.any()
        else:  # the light's edge pixels are noisy (about 1% here): means agree to 3%
            assert ref.mean() > 0.05
            np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.03)
