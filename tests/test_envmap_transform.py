"""An `envmap` with `scale` and a rotating `to_world` (Mitsuba docs scenes turn their sky
this way), rendered by rdsl and by Mitsuba 3 (scalar_rgb): the sky seen directly, and a
diffuse sphere lit by it (importance sampled through the rotation)."""

from __future__ import annotations

import numpy as np
import pytest
from _plugin_scenes import median_rmse, perspective, write_scene
from rdsl.runtime.render.image import write_exr

pytest.importorskip("rdsl.runtime.embree")
pytest.importorskip("mitsuba")

ROTATIONS = {
    "none": "",
    "y70": '<rotate y="1" angle="70"/>',
    "x20_y-110": '<rotate x="1" angle="20"/><rotate y="1" angle="-110"/>',
}


def _sky(tmp_path) -> str:
    """A sky with a bright warm patch and a colour gradient, so that rotations show."""
    h, w = 32, 64
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    img = np.stack([0.2 + 0.8 * x, 0.3 + 0.5 * y, 0.6 - 0.4 * x * y], axis=-1)
    img[6:12, 40:50] = (12.0, 8.0, 3.0)
    write_exr(tmp_path / "sky.exr", img.astype(np.float32))
    return str(tmp_path / "sky.exr")


@pytest.mark.parametrize("rotation", sorted(ROTATIONS))
def test_rotated_scaled_envmap_against_mitsuba(tmp_path, rotation):
    sky = _sky(tmp_path)
    body = f"""<shape type="sphere"><transform name="to_world"><scale value="0.8"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.7, 0.7"/></bsdf></shape>
  <emitter type="envmap"><string name="filename" value="{sky}"/>
    <float name="scale" value="1.7"/>
    <transform name="to_world">{ROTATIONS[rotation]}</transform></emitter>"""
    path = write_scene(tmp_path, body, perspective(origin="0, 0.5, 4", fov=60), max_depth=3,
                       room=False)
    mine, theirs = median_rmse(path, 32)
    assert mine <= 1.2 * theirs, (mine, theirs)
