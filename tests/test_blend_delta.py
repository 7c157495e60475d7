"""A `blendbsdf` of a smooth (delta) conductor and a diffuse BSDF is the blend of the two:
its image is the weighted sum of the images of each BSDF alone.  The truth here is Mitsuba 3's
own renders of each BSDF alone, summed; rdsl's blend must match it.

(Mitsuba 3.9.1's render of the blend itself does not: under a uniform environment of radiance
1 the mirror alone gives 1.0, the diffuse 0.1 alone 0.1, so weight 0.5 must give 0.55, and
rdsl gives 0.553 where Mitsuba's `path` and `direct` give 0.438; a blend of a rough conductor
and the diffuse agrees with its parts in both renderers.  Here, Mitsuba's blend is 11% below
the truth in red, rdsl's within noise of it.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant, scene_header

MIRROR = '<bsdf type="conductor"/>'
DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.3, 0.6"/></bsdf>'
WEIGHT = 0.3  # of the second BSDF, the diffuse one


def scene(bsdf: str) -> str:
    return scene_header("0, 0, 4", "0, 0, 0", "0, 1, 0", fov=30, res=16, max_depth=4) + f"""
  <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
  <shape type="rectangle">
    <transform name="to_world"><translate y="-1.2"/><rotate x="1" angle="-60"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.2, 0.2"/></bsdf></shape>
  <shape type="sphere"><float name="radius" value="0.8"/>{bsdf}</shape>
</scene>
"""


def test_blend_of_delta_and_diffuse_is_the_blend_of_their_images(tmp_path: Path) -> None:
    pytest.importorskip("rdsl.runtime.embree")
    from rdsl.runtime.render.renderer import load_scene
    parts = []
    with mitsuba_variant("scalar_rgb") as mi:
        for bsdf in (MIRROR, DIFFUSE):
            path = tmp_path / "part.xml"
            path.write_text(scene(bsdf))
            parts.append(np.array(mi.render(mi.load_file(str(path)), spp=256, seed=1))[..., :3])
    truth = (1 - WEIGHT) * parts[0] + WEIGHT * parts[1]
    path = tmp_path / "blend.xml"
    path.write_text(scene(f'<bsdf type="blendbsdf"><float name="weight" value="{WEIGHT}"/>'
                          f'{MIRROR}{DIFFUSE}</bsdf>'))
    ours = load_scene(path, variant="rgb", target="host").render(spp=256, seed=2)[..., :3]
    sphere = (slice(5, 11), slice(5, 11))
    a, b = ours[sphere].mean(axis=(0, 1)), truth[sphere].mean(axis=(0, 1))
    np.testing.assert_allclose(a, b, rtol=0.03)
