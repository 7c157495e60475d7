"""Mitsuba 3's `orthographic`, `radiancemeter` and `irradiancemeter` sensors
(stdlib/render/sensors.rdsl): images and measurements against Mitsuba 3 (scalar_rgb), an
analytic irradiance, and bad input naming the file and line."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from _mitsuba_compare import mitsuba_render
from _plugin_scenes import check_bad, film, median_rmse, write_scene
from rdsl.runtime.scene import load_scene_description

pytest.importorskip("rdsl.runtime.embree")
pytest.importorskip("mitsuba")

ORTHO = ('<sensor type="orthographic"><transform name="to_world"><scale x="1.5" y="1.5"/>'
         '<lookat origin="0.5, 0.3, 4" target="0.5, 0.3, 0" up="0, 1, 0"/></transform>'
         '{film}</sensor>')
BALL = ('<shape type="sphere"><transform name="to_world"><scale value="0.5"/></transform>'
        '<bsdf type="roughconductor"><float name="alpha" value="0.2"/></bsdf></shape>')


@pytest.mark.parametrize("crop", [False, True])
def test_orthographic_against_mitsuba(tmp_path, crop):
    """A scaled orthographic view of a sphere (a non-square film, and a crop window)."""
    f = film(32, 24)
    if crop:
        f = f.replace("<rfilter", '<integer name="crop_offset_x" value="8"/><integer name='
                      '"crop_width" value="16"/><integer name="crop_offset_y" value="4"/>'
                      '<integer name="crop_height" value="12"/><rfilter')
    path = write_scene(tmp_path, BALL, sensor=ORTHO.format(film=f))
    mine, theirs = median_rmse(path, 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


def _measure(path, spp: int = 65536, seeds: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The one pixel's value over several seeds, by rdsl and by Mitsuba."""
    scene = rdsl.load_scene(path)
    mine = np.array([scene.render(spp=spp, seed=k)[0, 0, :3] for k in range(seeds)])
    theirs = np.array([mitsuba_render(path, spp, seed=20 + k)[0, 0] for k in range(seeds)])
    return mine, theirs


def _agree(mine: np.ndarray, theirs: np.ndarray) -> None:
    """The means agree within 5 standard errors (and 0.5% for noise-free values)."""
    n = len(mine)
    se = np.sqrt(mine.var(axis=0) / n + theirs.var(axis=0) / n)
    diff = np.abs(mine.mean(axis=0) - theirs.mean(axis=0))
    assert (diff <= 5 * se + 5e-3 * theirs.mean(axis=0)).all(), (mine.mean(0), theirs.mean(0), se)


def test_radiancemeter_against_mitsuba(tmp_path):
    sensor = ('<sensor type="radiancemeter"><point name="origin" value="0, 0, 4"/>'
              f'<vector name="direction" value="0.1, 0.05, -1"/>{film(1)}</sensor>')
    _agree(*_measure(write_scene(tmp_path, "", sensor=sensor)))


def test_radiancemeter_to_world_is_origin_and_direction(tmp_path):
    a = ('<sensor type="radiancemeter"><point name="origin" value="0.2, 0, 4"/>'
         f'<vector name="direction" value="0, 0.1, -1"/>{film(1)}</sensor>')
    b = ('<sensor type="radiancemeter"><transform name="to_world"><lookat origin="0.2, 0, 4" '
         f'target="0.2, 0.1, 3"/></transform>{film(1)}</sensor>')
    rays = []
    for k, s in enumerate((a, b)):
        p = load_scene_description(write_scene(tmp_path, "", sensor=s, name=f"{k}.xml")).sensor
        rays.append(np.concatenate([p["origin"], p["direction"]]))
    np.testing.assert_allclose(rays[0], rays[1], atol=1e-12)


METER = ('<shape type="{shape}"><transform name="to_world"><scale value="0.3"/>'
         '<rotate x="1" angle="30"/><translate y="0.2" z="0.5"/></transform>{flip}'
         '<sensor type="irradiancemeter">{film}</sensor></shape>')


@pytest.mark.parametrize("shape", ["rectangle", "disk", "sphere", "rectangle_flipped"])
def test_irradiancemeter_against_mitsuba(tmp_path, shape):
    """The mean irradiance over a tilted rectangle or disk (front or back), a sphere.  The
    sphere is not rotated: Mitsuba 3.9.1's mean over a sphere changes when the sphere is
    rotated (0.885 unrotated, 0.846 turned 30 degrees about x, under the sky and the wall
    alone), which the physics does not; rdsl's does not change
    (test_irradiancemeter_on_a_sphere_ignores_its_rotation)."""
    kind, _, flipped = shape.partition("_")
    flip = '<boolean name="flip_normals" value="true"/>' if flipped else ""
    body = METER.format(shape=kind, flip=flip, film=film(1))
    if kind == "sphere":
        body = body.replace('<rotate x="1" angle="30"/>', "")
    _agree(*_measure(write_scene(tmp_path, body, sensor=" ")))


def test_irradiancemeter_on_a_sphere_ignores_its_rotation(tmp_path):
    means = []
    for k, rot in enumerate(("", '<rotate x="1" angle="30"/>', '<rotate y="1" angle="70"/>')):
        body = METER.format(shape="sphere", flip="", film=film(1)).replace(
            '<rotate x="1" angle="30"/>', rot)
        scene = rdsl.load_scene(write_scene(tmp_path, body, sensor=" ", name=f"{k}.xml"))
        means.append([scene.render(spp=65536, seed=s)[0, 0, 0] for s in range(8)])
    means = np.array(means)
    se = means.std(axis=1).max() / np.sqrt(8)
    assert np.ptp(means.mean(axis=1)) <= 5 * np.sqrt(2) * se, means.mean(axis=1)


def test_irradiancemeter_under_a_uniform_sky_is_pi_times_its_radiance(tmp_path):
    """Nothing else in the scene: every sample is pi L exactly."""
    path = tmp_path / "sky.xml"
    path.write_text('<scene version="3.0.0">' + METER.format(shape="disk", flip="", film="")
                    + '<emitter type="constant"><rgb name="radiance" value="0.5, 0.25, 2"/>'
                    '</emitter></scene>')
    img = rdsl.load_scene(path).render(spp=64)
    assert img.shape[:2] == (1, 1)  # a one-pixel film by default
    np.testing.assert_allclose(img[0, 0, :3], np.pi * np.array([0.5, 0.25, 2]), rtol=1e-5)


BAD = {
    "meter_film": (f'<sensor type="radiancemeter">{film(2)}</sensor>',
                   "radiancemeter: the film must be 1x1 pixels"),
    "origin_only": (('<sensor type="radiancemeter"><point name="origin" value="0, 0, 1"/>'
                    '</sensor>'), "give both 'origin' and 'direction' (missing 'direction')"),
    "both_forms": (('<sensor type="radiancemeter"><transform name="to_world"><translate x="1"/>'
                   '</transform><point name="origin" value="0, 0, 1"/><vector name="direction"'
                   ' value="0, 0, 1"/></sensor>'), "give either 'to_world' or 'origin'"),
    "zero_direction": (('<sensor type="radiancemeter"><point name="origin" value="0, 0, 1"/>'
                       '<vector name="direction" value="0, 0, 0"/></sensor>'),
                       "'direction' is zero"),
    "direction_type": (('<sensor type="radiancemeter"><float name="direction" value="1"/>'
                       '</sensor>'), ("parameter 'direction' of sensor 'radiancemeter' expects a "
                       "vector, got <float>")),
    "meter_top": ('<sensor type="irradiancemeter"/>', "must be nested inside the <shape>"),
    "meter_mesh": ('<shape type="cube"><sensor type="irradiancemeter"/></shape>',
                   "not on a 'cube' shape"),
    "camera_in_shape": ('<shape type="disk"><sensor type="perspective"/></shape>',
                        "only an 'irradiancemeter' sensor can be nested in a <shape>"),
    "ortho_fov": ('<sensor type="orthographic"><float name="fov" value="30"/></sensor>',
                  "unknown parameter 'fov' of sensor 'orthographic'"),
    "ortho_clip": (('<sensor type="orthographic"><float name="near_clip" value="0"/>'
                   '</sensor>'), "'near_clip' must be greater than zero"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_sensor(tmp_path, case):
    check_bad(tmp_path, *BAD[case])
