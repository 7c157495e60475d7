"""Mitsuba 3's `moment` integrator (stdlib/integrator/moment.rdsl): its channels as Mitsuba
names them, its images against Mitsuba 3 (scalar_rgb), the XYZ and second-moment identities,
and what it refuses."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from _mitsuba_render import mitsuba_variant
from _plugin_scenes import write_scene
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.scene import SceneError

pytest.importorskip("rdsl.runtime.embree")

BALL = ('<shape type="sphere"><transform name="to_world"><scale value="0.5"/></transform>'
        '<bsdf type="roughconductor"><float name="alpha" value="0.3"/></bsdf></shape>')
DIFFUSE_BALL = BALL.replace('<bsdf type="roughconductor"><float name="alpha" value="0.3"/>'
                            '</bsdf>', "")
SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])


def _moment(nested: str) -> str:
    return f'<integrator type="moment">{nested}</integrator>'


@pytest.mark.parametrize("name", ['name="pt"', ""])
def test_channels_are_named_as_mitsuba_names_them(tmp_path, name):
    path = write_scene(tmp_path, BALL, integrator=_moment(f'<integrator type="path" {name}/>'))
    with mitsuba_variant("scalar_rgb") as mi:
        theirs = list(mi.load_file(str(path)).integrator().aov_names())
    assert rdsl.load_scene(path).channel_names == ["R", "G", "B", *theirs]


@pytest.mark.parametrize("nested", ["path", "depth"])
def test_moment_against_mitsuba(tmp_path, nested):
    """Every channel (radiance, XYZ, second moments) within 1.2x of Mitsuba's RMSE at
    equal spp (medians of three seeds) against a 4096-spp Mitsuba render, and the second
    moments' image means within 3%, over a path tracer (diffuse: the second moment is the
    mean of the squared sample, so it depends on the nested estimator's per-sample
    variance, which for glossy paths is not Mitsuba's exactly) and over `depth`."""
    inner = (f'<integrator type="{nested}" name="pt"><integer name="max_depth" value="4"/>'
             '</integrator>' if nested == "path" else f'<integrator type="{nested}"/>')
    path = write_scene(tmp_path, DIFFUSE_BALL, integrator=_moment(inner))
    with mitsuba_variant("scalar_rgb") as mi:
        scene_mi = mi.load_file(str(path))
        ref = np.array(mi.render(scene_mi, spp=4096, seed=100), np.float64)
        theirs = [np.array(mi.render(scene_mi, spp=32, seed=10 + k), np.float64)
                  for k in range(3)]
    scene = rdsl.load_scene(path)
    mine = [np.asarray(scene.render(spp=32, seed=k), np.float64) for k in range(3)]
    assert mine[0].shape == ref.shape
    for chans in (slice(0, 3), slice(3, 6), slice(6, 9)):
        def err(img: np.ndarray, chans: slice = chans) -> float:
            return float(np.sqrt(np.mean((img[..., chans] - ref[..., chans]) ** 2)))
        a, b = np.median([err(x) for x in mine]), np.median([err(x) for x in theirs])
        assert a <= 1.2 * b, (chans, a, b)
    np.testing.assert_allclose(np.mean(mine, axis=0)[..., 6:9].mean(axis=(0, 1)),
                               ref[..., 6:9].mean(axis=(0, 1)), rtol=0.03)


def test_xyz_is_the_radiance_and_m2_bounds_its_square(tmp_path):
    """Per pixel, the XYZ channels are the sRGB-to-XYZ matrix times the RGB ones (a linear
    map commutes with the film's mean), and the second moment is at least the square of the
    mean (Jensen), with equality where every sample is the same (the sky seen directly)."""
    path = write_scene(tmp_path, BALL, integrator=_moment('<integrator type="path"/>'))
    img = np.asarray(rdsl.load_scene(path).render(spp=16, seed=1), np.float64)
    rgb, xyz, m2 = img[..., 0:3], img[..., 3:6], img[..., 6:9]
    np.testing.assert_allclose(xyz, rgb @ SRGB_TO_XYZ.T, rtol=1e-4, atol=1e-6)
    assert (m2 >= xyz ** 2 * (1 - 1e-4) - 1e-7).all()
    sky = tmp_path / "sky.xml"
    sky.write_text(path.read_text().replace(BALL, "").split("<shape")[0] +
                   '<emitter type="constant"><rgb name="radiance" value="0.3, 0.5, 0.7"/>'
                   '</emitter></scene>')
    img = np.asarray(rdsl.load_scene(sky).render(spp=4, seed=1), np.float64)
    np.testing.assert_allclose(img[..., 6:9], img[..., 3:6] ** 2, rtol=1e-5)
    np.testing.assert_allclose(img[0, 0, 3:6], SRGB_TO_XYZ @ [0.3, 0.5, 0.7], rtol=1e-5)


def test_mono_is_the_luminance_three_times(tmp_path):
    path = write_scene(tmp_path, BALL, integrator=_moment('<integrator type="path"/>'))
    img = rdsl.load_scene(path, variant="mono").render(spp=4, seed=1)
    np.testing.assert_allclose(img[..., 1:4], np.repeat(img[..., :1], 3, axis=-1), rtol=1e-6)


def test_refused_where_it_cannot_run(tmp_path):
    path = write_scene(tmp_path, BALL, integrator=_moment('<integrator type="path"/>'))
    with pytest.raises(CompileError, match="moment: rdsl computes this integrator's XYZ "
                       "moments in the `mono` and `rgb` variants only, not `spectral`"):
        rdsl.load_scene(path, variant="spectral").render(spp=1)
    two = write_scene(tmp_path, BALL, name="two.xml", integrator=_moment(
        '<integrator type="path"/><integrator type="direct"/>'))
    with pytest.raises(CompileError, match="at most one nested integrator"):
        rdsl.load_scene(two).render(spp=1)
    none = write_scene(tmp_path, BALL, name="none.xml", integrator=_moment(""))
    with pytest.raises(SceneError, match=r"none.xml:2:.*integrator 'moment' takes 1 to 8 "
                       "nested <integrator>, got 0"):
        rdsl.load_scene(none)
    bad = write_scene(tmp_path, BALL, name="bad.xml", integrator=(
        '<integrator type="moment"><integer name="max_depth" value="3"/></integrator>'))
    with pytest.raises(SceneError, match=r"bad.xml:2:.*unknown parameter 'max_depth' of "
                       "integrator 'moment'"):
        rdsl.load_scene(bad)
