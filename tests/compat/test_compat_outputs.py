"""The film's and the integrators' outputs beyond test_compat_suite's noise-aware test of each
tile (tests/compat/_cases_outputs.py): a crop window is that window of the whole image, a
crop that does not fit is refused at its line (as Mitsuba 3 refuses it), pixel formats, and
the deterministic AOVs pixel by pixel against Mitsuba's reference."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from _cases_outputs import CROPS
from _sheet import RATIO, TILE, noise_table, ref_path, rdsl_images, rmse
from _suite import BY_NAME

pytest.importorskip("rdsl.runtime.embree")


@pytest.mark.parametrize("name", sorted(CROPS))
def test_crop_is_the_window_of_the_whole_image(name):
    """rdsl's crop against the same window of Mitsuba's reference of the whole film (the
    sheet of the same scene without the crop), tile by tile, at Mitsuba's own noise."""
    from rdsl.runtime.render.image import read_exr

    sh, whole = BY_NAME[name], BY_NAME[name.split(".", 1)[1]]
    x, y, w, h = sh.crop
    window = read_exr(ref_path(whole)).astype(np.float64)[y:y + h, x:x + w]
    mine = rdsl_images(sh)
    assert mine[0].shape == window.shape, (mine[0].shape, window.shape)
    noise = noise_table()[name]["rmse"]
    for i, c in enumerate(sh.cases):
        ours = float(np.median([rmse(sh.tile(m, i), sh.tile(window, i)) for m in mine]))
        assert ours <= RATIO * noise[c.name], (c.name, ours, noise[c.name])


def _film_scene(tmp_path, film: str):
    path = tmp_path / "film.xml"
    path.write_text(f"""<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <film type="hdrfilm"><integer name="width" value="{TILE}"/>
      <integer name="height" value="16"/>
      {film}
    </film>
  </sensor>
  <shape type="sphere"><bsdf type="diffuse"/></shape>
  <emitter type="constant"/>
</scene>""")
    return path


@pytest.mark.parametrize("crop,line", [
    ('<integer name="crop_offset_x" value="10"/><integer name="crop_width" value="20"/>', 5),
    ('<integer name="crop_height" value="17"/>', 5),
    ('<integer name="crop_offset_y" value="-1"/>', 5)])
def test_a_crop_that_does_not_fit_is_refused_at_its_line(tmp_path, crop, line):
    from rdsl.runtime.render.renderer import load_scene

    path = _film_scene(tmp_path, crop)
    with pytest.raises(Exception) as e:
        load_scene(path)
    assert f"{path}:{line}" in str(e.value) and "crop" in str(e.value), str(e.value)
    assert "Traceback" not in str(e.value)
    try:
        import mitsuba as mi
        mi.set_variant("scalar_rgb")
    except (ImportError, AttributeError):
        return
    with pytest.raises(Exception):  # Mitsuba 3 refuses it too
        mi.load_file(str(path))


def test_pixel_formats(tmp_path):
    """Each pixel_format's channels, as Mitsuba's film names them, with no warning: Y
    (luminance, Mitsuba's luminance of the colour; the noise-aware check is the
    `luminance` sheet), R, G, B, A, X, Y, Z (A) and Y, A (values: tests/test_film_alpha.py)."""
    from rdsl.runtime.render.renderer import load_scene

    for fmt, names in (("luminance", ["Y"]), ("rgba", ["R", "G", "B", "A"]),
                       ("luminance_alpha", ["Y", "A"]), ("xyz", ["X", "Y", "Z"]),
                       ("xyza", ["X", "Y", "Z", "A"])):
        path = _film_scene(tmp_path, f'<string name="pixel_format" value="{fmt}"/>')
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            scene = load_scene(path)
        assert scene.channel_names == names


# the AOVs that do not depend on the light: the same at any spp but for the pixels' coverage
DETERMINISTIC = ("aov.depth", "aov.position", "aov.uv", "aov.geo_normal", "aov.sh_normal",
                 "aov.dp_du", "aov.dp_dv", "depth")
EDGE = 0.35  # a pixel may be off by this fraction of how much its 3x3 neighbourhood varies


def _spread(a: np.ndarray) -> np.ndarray:
    """max - min over each pixel's 3x3 neighbourhood (the image's edge repeated)."""
    p = np.pad(a, 1, mode="edge")
    n = np.stack([p[i:i + a.shape[0], j:j + a.shape[1]] for i in range(3) for j in range(3)])
    return n.max(0) - n.min(0)


@pytest.mark.parametrize("name", DETERMINISTIC)
def test_deterministic_aovs_pixel_by_pixel(name):
    """Each pixel of each channel against Mitsuba's reference: all but 0.5% of the pixels
    within 1e-3 of the channel's scale plus EDGE times the reference's variation around the
    pixel (at an edge the pixel's coverage of two surfaces is estimated from the test's
    spp; the few left out are where thin features, a cylinder's rim, cross a pixel)."""
    from rdsl.runtime.render.image import read_exr

    ref = read_exr(ref_path(BY_NAME[name])).astype(np.float64)
    mine = rdsl_images(BY_NAME[name])[0]
    assert mine.shape == ref.shape
    for k in range(ref.shape[-1]):
        r = ref[..., k]
        spread = _spread(r)
        tol = 1e-3 * max(np.abs(r).max(), 1e-3) + EDGE * spread
        bad = np.abs(mine[..., k] - r) > tol
        assert bad.mean() < 0.005, (name, k, int(bad.sum()), np.argwhere(bad)[:5].tolist())
