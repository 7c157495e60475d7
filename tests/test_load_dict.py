"""``rdsl.load_dict``: Mitsuba 3's Python scene dictionaries.  The Cornell box written as the
dictionary Mitsuba's ``mi.cornell_box()`` gives renders the same image as its XML file, and
each kind of mistake is an error naming the key path."""

from __future__ import annotations

import numpy as np
import pytest
from _scenes import CBOX

import rdsl
from rdsl.runtime.scene import SceneError

T = rdsl.Transform4f


def rgb(*v):
    return {"type": "rgb", "value": list(v)}


def cornell_box(res: int = 16, spp: int = 4) -> dict:
    """examples/cbox/cbox.xml as a dictionary; a transform chain applies its last call first,
    as Mitsuba's (``T().translate(t).rotate(a, x)`` rotates, then translates)."""
    white, green, red = (rgb(0.885809, 0.698859, 0.666422), rgb(0.105421, 0.37798, 0.076425),
                         rgb(0.570068, 0.0430135, 0.0443706))
    ref = {"type": "ref", "id": "white"}

    def wall(t, bsdf="white"):
        return {"type": "rectangle", "to_world": t, "bsdf": {"type": "ref", "id": bsdf}}

    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 8},
        "sensor": {
            "type": "perspective", "fov_axis": "smaller", "near_clip": 0.001,
            "far_clip": 100.0, "focus_distance": 1000.0, "fov": 39.3077,
            "to_world": T.look_at(origin=[0, 0, 3.9], target=[0, 0, 0], up=[0, 1, 0]),
            "sampler": {"type": "independent", "sample_count": spp},
            "film": {"type": "hdrfilm", "width": res, "height": res,
                     "rfilter": {"type": "gaussian"}, "pixel_format": "rgb",
                     "component_format": "float32"},
        },
        "white": {"type": "diffuse", "reflectance": white},
        "green": {"type": "diffuse", "reflectance": green},
        "red": {"type": "diffuse", "reflectance": red},
        "light": {"type": "rectangle", "to_world": T().translate([0, 0.99, 0.01])
                  .scale([0.23, 0.19, 0.19]).rotate([1, 0, 0], 90), "bsdf": ref,
                  "emitter": {"type": "area", "radiance": rgb(18.387, 13.9873, 6.75357)}},
        "floor": wall(T().translate([0, -1, 0]).rotate([1, 0, 0], -90)),
        "ceiling": wall(T().translate([0, 1, 0]).rotate([1, 0, 0], 90)),
        "back": wall(T().translate([0, 0, -1])),
        "green-wall": wall(T().translate([1, 0, 0]).rotate([0, 1, 0], -90), "green"),
        "red-wall": wall(T().translate([-1, 0, 0]).rotate([0, 1, 0], 90), "red"),
        "small-box": {"type": "cube", "bsdf": ref, "to_world": T().translate(
            [0.335, -0.7, 0.38]).rotate([0, 1, 0], -17).scale(0.3)},
        "large-box": {"type": "cube", "bsdf": ref, "to_world": T().translate(
            [-0.33, -0.4, -0.28]).rotate([0, 1, 0], 18.25).scale([0.3, 0.61, 0.3])},
    }


def test_cornell_box_dict_renders_as_its_xml():
    ours = rdsl.load_dict(cornell_box()).render(seed=2)
    xml = rdsl.load_scene(CBOX, res=16, spp=4).render(seed=2)
    assert ours.shape == xml.shape == (16, 16, 3)
    assert np.array_equal(ours, xml)  # the same scene, bit for bit


@pytest.mark.parametrize("scene, message", [
    ([1, 2], "expected a dict"),
    ({"type": "shape"}, "must have \"type\": \"scene\""),
    ({"type": "scene", "a": {"type": "difuse"}},
     "scene['a']: unknown plugin type 'difuse' (did you mean 'diffuse'"),
    ({"type": "scene", "a": {"type": "diffuse", "reflectance": {"value": 1}}},
     "scene['a']['reflectance']: a nested dict needs a \"type\""),
    ({"type": "scene", "a": {"type": "diffuse", "reflectance": rgb(1, 2)}},
     "an rgb value has 1 or 3 numbers"),
    ({"type": "scene", "a": {"type": "diffuse", "reflectance": object()}},
     "cannot use a object"),
])
def test_dict_mistakes_name_the_key(scene, message):
    with pytest.raises(SceneError) as e:
        rdsl.load_dict(scene)
    assert message in str(e.value)


@pytest.mark.parametrize("key, value, message", [
    ("roughness", 0.3, "unknown parameter 'roughness' of bsdf 'diffuse'"),
    ("reflectance", True, "parameter 'reflectance' of bsdf 'diffuse'"),
    ("reflectance", {"type": "ref", "id": "nowhere"}, "<ref>: no object with id 'nowhere'"),
])
def test_a_loader_error_names_the_key_not_the_written_xml(key, value, message):
    """Errors the scene loader finds (it reads the XML the dict is written as) name the
    dict's key path, not a line of that file, which the user never wrote."""
    bad = cornell_box()
    bad["white"][key] = value
    with pytest.raises(SceneError) as e:
        rdsl.load_dict(bad)
    text = str(e.value)
    assert text.startswith(f"error: load_dict: scene['white'][{key!r}]: {message}"), text
    assert "dicts" not in text and ".xml" not in text, text  # the cache's file is not named
    assert f'name="{key}"' in text, text  # what the value was written as


def test_a_dict_error_the_loader_finds_is_reported():
    bad = cornell_box()
    bad["white"]["reflectance"] = 0.5
    bad["white"]["roughness"] = 0.3  # diffuse has no such parameter
    with pytest.raises(SceneError, match="roughness"):
        rdsl.load_dict(bad)
