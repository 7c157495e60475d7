"""Each BSDF's ``smooth()`` (stdlib/render/scene.rdsl's ``scene_bsdf_smooth``: the path and
direct integrators sample emitters only at BSDFs that have a non-delta lobe) against
Mitsuba 3's own flag, ``BSDFFlags::Smooth``, of the same plugin."""

import mitsuba as mi
import pytest

from rdsl.runtime.testkit.harness import Harness

mi.set_variant("scalar_rgb")

# a smooth lobe (diffuse, plastic's base, microfacets) or delta lobes only
NAMES = ("diffuse", "plastic", "roughconductor", "conductor", "dielectric", "thindielectric",
         "null")


@pytest.mark.parametrize("name", NAMES)
def test_smooth_matches_mitsuba(name):
    flags = mi.load_dict({"type": name}).flags()
    expected = mi.has_flag(flags, mi.BSDFFlags.Smooth)
    assert Harness(name, "rgb").smooth() == expected
