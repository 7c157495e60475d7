"""Values that parse but cannot be rendered: a NaN clip distance, an infinite field of view or
rotation angle, a filter of NaN width, a film too large for the kernels' 32-bit indices.  Each is an error at
its line (found by rendering scenes whose numbers were replaced by extreme ones), while an
infinite ``far_clip``, which means something, renders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _scenes import CBOX, edited_copy
from rdsl.runtime.scene import SceneError, load_scene_description

CAMERA = ['<sensor type="perspective">', '    <float name="{name}" value="{value}"/>',
          '    <film type="hdrfilm"><integer name="width" value="8"/>'
          '<integer name="height" value="8"/></film>', '</sensor>']

# (lines after <scene>, the line of the error, a part of its message)
BAD_VALUES = {
    "nan_far_clip": ([s.format(name="far_clip", value="nan") for s in CAMERA], 3,
                     "'far_clip' is not a number (nan)"),
    "nan_near_clip": ([s.format(name="near_clip", value="nan") for s in CAMERA], 3,
                      "'near_clip' is not a number (nan)"),
    "nan_focus_distance": ([s.format(name="focus_distance", value="nan") for s in CAMERA], 3,
                           "'focus_distance' is not a number (nan)"),
    "infinite_fov": ([s.format(name="fov", value="inf") for s in CAMERA], 3,
                     "'fov' must be between 0 and 180 degrees, got inf"),
    "nan_fov": ([s.format(name="fov", value="nan") for s in CAMERA], 3,
                "'fov' must be between 0 and 180 degrees, got nan"),
    "nan_filter": (['<sensor type="perspective">', '    <film type="hdrfilm">',
                    '        <rfilter type="gaussian"><float name="stddev" value="nan"/>'
                    '</rfilter>', '    </film>', '</sensor>'], 4,
                   "rfilter 'gaussian': 'stddev' must be positive and finite"),
    "infinite_filter": (['<sensor type="perspective">', '    <film type="hdrfilm">',
                         '        <rfilter type="tent"><float name="radius" value="inf"/>'
                         '</rfilter>', '    </film>', '</sensor>'], 4,
                        "rfilter 'tent': 'radius' must be positive and finite"),
    "infinite_angle": (['<shape type="sphere">', '    <transform name="to_world">',
                        '        <rotate y="1" angle="inf"/>', '    </transform>', '</shape>'],
                       4, "<rotate>: the angle must be finite, got inf"),
    "nan_translation": (['<shape type="sphere">', '    <transform name="to_world">',
                         '        <translate x="1" y="nan"/>', '    </transform>', '</shape>'],
                        4, "<translate>: a number is not finite"),
    "infinite_lookat": (['<sensor type="perspective">', '    <transform name="to_world">',
                         '        <lookat origin="0, 0, inf" target="0, 0, 0"/>',
                         '    </transform>', '</sensor>'], 4, "<lookat>: its points must be finite"),
    "film_too_large": (['<sensor type="perspective">', '    <film type="hdrfilm">',
                        '        <integer name="width" value="33554432"/>',
                        '        <integer name="height" value="256"/>', '    </film>',
                        '</sensor>'], 4, "33554432 x 256 pixels is more than the 1073741824"),
}


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_value_that_cannot_be_rendered_is_an_error_at_its_line(tmp_path: Path, case: str):
    body, line, message = BAD_VALUES[case]
    path = tmp_path / "scene.xml"
    path.write_text("\n".join(['<scene version="3.0.0">', *body, "</scene>"]) + "\n")
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    text = str(exc.value)
    assert message in text, text
    assert text.startswith(f"{path}:{line}:"), text


@pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")
def test_an_infinite_far_clip_renders_as_a_far_one(tmp_path: Path):
    """The camera's constants are written into the kernel's source: an infinite one as the
    prelude's ``infinity()`` (no literal spells it), and the image is the finite clip's."""
    pytest.importorskip("rdsl.runtime.embree")
    from rdsl.runtime.render.renderer import load_scene

    path = edited_copy(CBOX, tmp_path, 'name="far_clip" value="100.0"',
                       'name="far_clip" value="inf"')
    far = load_scene(path, res=8)
    got = far.render(spp=2, seed=4)
    assert "infinity()" in far.kernel_src
    want = load_scene(CBOX, res=8).render(spp=2, seed=4)
    assert np.isfinite(got).all() and got.max() > 0
    np.testing.assert_array_equal(got, want)


def test_a_nan_estimate_is_left_out_of_every_pixel(tmp_path: Path):
    """A user BSDF given a NaN parameter (orennayar's sigma) makes every path that meets it
    NaN: those samples are counted and left out of the film, value and weight, so no pixel
    turns NaN (their value was multiplied by 0, and NaN * 0 reached every pixel the
    sample's filter does)."""
    pytest.importorskip("rdsl.runtime.embree")
    from rdsl.runtime.render.renderer import load_scene

    example = Path(__file__).resolve().parents[1] / "examples/plugins/orennayar.xml"
    path = edited_copy(example, tmp_path, 'name="sigma" value="40"', 'name="sigma" value="nan"')
    for variant in ("rgb", "spectral"):
        scene = load_scene(path, variant=variant, res=16)
        img = scene.render(spp=4, seed=1)
        assert scene.nonfinite > 0, variant
        assert np.isfinite(img).all(), f"{variant}: {int(np.isnan(img).sum())} NaN values"
        assert img.mean() > 0.05, variant  # the rest of the box is still lit
