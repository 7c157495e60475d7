"""Mitsuba's `aov` integrator with a nested integrator writes the nested image as channels
``_arg_0.R``, ``.G``, ``.B``, ``.A`` (under the nested integrator's ``name`` if it has one)
between the film's colour (and alpha) and the AOVs, in an rgb film as well as an rgba one:
rdsl's channel names, in order, against Mitsuba 3.9's film, and their values noise-aware
(the colour is the nested integrator's estimate, the alpha its `valid`)."""

from __future__ import annotations

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant
from test_film_alpha import (
    CONSTANT,
    MASK,
    PATH,
    assert_alpha_matches,
    assert_colour_matches,
    colour,
    scene_xml,
)

pytest.importorskip("rdsl.runtime.embree")

AOVS = '<string name="aovs" value="dd:depth,nn:sh_normal"/>'
CASES = {  # name -> (film pixel format, nested integrators, background)
    "rgb.path": ("rgb", PATH, ""),
    "rgba.path": ("rgba", PATH, ""),
    "rgba.direct.constant": ("rgba", '<integrator type="direct"/>', CONSTANT),
    "rgb.named": ("rgb", '<integrator type="path" name="beauty"/>', CONSTANT),
    "spectral.rgba.path": ("rgba", PATH, ""),
}


def render_both(tmp_path, xml: str, variant: str, spp: int = 64, mi_spp: int = 512):
    """(channel names in film order, channels by name) of rdsl's render and Mitsuba's, in
    ``variant`` (Mitsuba's scalar one)."""
    from rdsl.runtime.render.image import read_exr_channels, write_render
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "scene.xml"
    path.write_text(xml)
    with mitsuba_variant(f"scalar_{variant}") as mi:
        sc = mi.load_file(str(path))
        mi.render(sc, spp=mi_spp, seed=3)
        film = sc.sensors()[0].film()
        film.write(str(tmp_path / "mitsuba.exr"))
        theirs_names = [f.name for f in film.bitmap().struct_()]
    scene = load_scene(path, variant=variant, target="host")
    write_render(tmp_path / "rdsl.exr", scene.render(spp=spp, seed=5), scene.channel_names)
    return ((scene.channel_names, read_exr_channels(tmp_path / "rdsl.exr")),
            (theirs_names, read_exr_channels(tmp_path / "mitsuba.exr")))


@pytest.mark.parametrize("name", sorted(CASES))
def test_nested_image_channels_are_mitsubas(tmp_path, name):
    """Names and order of every channel, then the nested image's colour and alpha (and
    the film's colour, which is the nested estimate too) against Mitsuba's."""
    fmt, nested, background = CASES[name]
    xml = scene_xml(f'<integrator type="aov">{AOVS}{nested}</integrator>', fmt, MASK,
                    background)
    variant = "spectral" if name.startswith("spectral") else "rgb"
    (our_names, ours), (their_names, theirs) = render_both(tmp_path, xml, variant)
    assert our_names == their_names, (our_names, their_names)
    image = "beauty" if "named" in name else "_arg_0"
    assert f"{image}.A" in our_names
    assert_alpha_matches(ours[f"{image}.A"], theirs[f"{image}.A"], 64, 512, name)
    for prefix in (f"{image}.", ""):
        assert_colour_matches(colour(ours, [f"{prefix}{c}" for c in "RGB"]),
                              colour(theirs, [f"{prefix}{c}" for c in "RGB"]), name)
    # the same samples: the copy is the film's colour itself
    np.testing.assert_array_equal(colour(ours, [f"{image}.{c}" for c in "RGB"]),
                                  colour(ours, "RGB"))
