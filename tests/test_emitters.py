"""Point, spot, directional, constant and envmap emitters in the path tracer, on tiny scenes
whose answer is analytic: a diffuse plane (reflectance RHO, normal +z) seen from straight
above through a narrow field of view, so every pixel sees nearly the point below the camera.
The envmap's importance sampling is checked against its own pdf (chi-square over bins)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.render.image import write_exr
from rdsl.runtime.render.renderer import load_scene

RHO = 0.5
PLANE = f"""<shape type="rectangle"><transform name="to_world"><scale value="10"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="{RHO}"/></bsdf></shape>"""


def scene_xml(emitters: str, plane: bool = True, res: int = 8, fov: float = 1.0) -> str:
    return f"""<scene version="3.0.0">
  <integrator type="path"/>
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="0,0,4" target="0,0,0" up="0,1,0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/><rfilter type="box"/></film></sensor>
  {PLANE if plane else ""}
  {emitters}
</scene>"""


def render(tmp_path: Path, emitters: str, spp: int = 16, **kw) -> np.ndarray:
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(emitters, **kw))
    scene = load_scene(path)
    img = scene.render(spp=spp, seed=3)
    assert scene.nonfinite == 0
    return img


def mean(img: np.ndarray) -> np.ndarray:
    return img.mean(axis=(0, 1))


# The pixels see points up to 0.035 off the center, where 1/r^2 and cos fall by ~0.1 %.
FOOTPRINT = 3e-3


def test_point_light_over_diffuse_plane(tmp_path):
    img = render(tmp_path, """<emitter type="point"><point name="position" x="0" y="0" z="2"/>
        <rgb name="intensity" value="10, 20, 40"/></emitter>""")
    expected = RHO / math.pi * np.array([10, 20, 40]) / 2.0**2
    np.testing.assert_allclose(mean(img), expected, rtol=FOOTPRINT)


def test_point_light_from_to_world(tmp_path):
    img = render(tmp_path, """<emitter type="point"><rgb name="intensity" value="10"/>
        <transform name="to_world"><translate z="1"/></transform></emitter>""")
    np.testing.assert_allclose(mean(img), RHO / math.pi * 10.0, rtol=FOOTPRINT)


def test_spot_inside_its_beam_equals_a_point_light(tmp_path):
    spot = render(tmp_path, """<emitter type="spot"><rgb name="intensity" value="10"/>
        <float name="cutoff_angle" value="30"/>
        <transform name="to_world"><lookat origin="0,0,1" target="0,0,0" up="0,1,0"/>
        </transform></emitter>""")
    point = render(tmp_path, """<emitter type="point"><point name="position" x="0" y="0" z="1"/>
        <rgb name="intensity" value="10"/></emitter>""")
    np.testing.assert_allclose(spot, point, rtol=1e-5)
    np.testing.assert_allclose(mean(spot), RHO / math.pi * 10.0, rtol=FOOTPRINT)


def test_spot_falls_off_linearly_in_angle_and_cuts_off(tmp_path):
    # Mitsuba 3's falloff_curve: 1 inside beam_width, (cutoff - angle) / (cutoff - beam) up
    # to cutoff_angle, 0 beyond.  The spot above the origin is tilted by 25 degrees.
    t = math.tan(math.radians(25.0))
    spot = """<emitter type="spot"><rgb name="intensity" value="10"/>
        <float name="cutoff_angle" value="{c}"/><float name="beam_width" value="20"/>
        <transform name="to_world"><lookat origin="0,0,1" target="{t},0,0" up="0,1,0"/>
        </transform></emitter>"""
    img = render(tmp_path, spot.format(c=30, t=t))
    np.testing.assert_allclose(mean(img), RHO / math.pi * 10.0 * 0.5, rtol=1e-2)
    dark = render(tmp_path, spot.format(c=22, t=t))  # the pixels see 23 to 27 degrees
    assert np.all(dark == 0.0)


def test_directional_light(tmp_path):
    img = render(tmp_path, """<emitter type="directional"><vector name="direction" x="0" y="0"
        z="-1"/><rgb name="irradiance" value="3"/></emitter>""")
    np.testing.assert_allclose(mean(img), RHO / math.pi * 3.0, rtol=1e-5)
    # at 60 degrees from the normal the plane receives E cos(60)
    img = render(tmp_path, f"""<emitter type="directional"><vector name="direction"
        x="{math.sin(math.radians(60))}" y="0" z="{-math.cos(math.radians(60))}"/>
        <rgb name="irradiance" value="3"/></emitter>""")
    np.testing.assert_allclose(mean(img), RHO / math.pi * 3.0 * 0.5, rtol=1e-4)


def test_constant_environment_seen_directly(tmp_path):
    img = render(tmp_path, '<emitter type="constant"><rgb name="radiance" value="2, 3, 4"/>'
                 '</emitter>', plane=False)
    assert np.all(img == np.array([2, 3, 4], np.float32))


def test_diffuse_plane_under_a_constant_environment(tmp_path):
    img = render(tmp_path, '<emitter type="constant"><rgb name="radiance" value="2"/></emitter>',
                 spp=256)
    np.testing.assert_allclose(mean(img), RHO * 2.0, rtol=1e-2)


def test_emitters_add_up_with_uniform_emitter_choice(tmp_path):
    # three emitters of different kinds: each is picked with probability 1/3
    img = render(tmp_path, """<emitter type="constant"><rgb name="radiance" value="2"/></emitter>
        <emitter type="point"><point name="position" x="0" y="0" z="1"/>
        <rgb name="intensity" value="10"/></emitter>
        <emitter type="directional"><vector name="direction" x="0" y="0" z="-1"/>
        <rgb name="irradiance" value="3"/></emitter>""", spp=512)
    expected = RHO * 2.0 + RHO / math.pi * (10.0 + 3.0)
    np.testing.assert_allclose(mean(img), expected, rtol=1.5e-2)


def _envmap(tmp_path: Path, image: np.ndarray, extra: str = "", name: str = "env.exr") -> str:
    write_exr(tmp_path / name, image.astype(np.float32))
    return (f'<emitter type="envmap"><string name="filename" value="{tmp_path / name}"/>'
            f'{extra}</emitter>')


def test_constant_envmap_equals_constant(tmp_path):
    env = _envmap(tmp_path, np.full((8, 16, 3), 0.5), '<float name="scale" value="4"/>')
    direct = render(tmp_path, env, plane=False)
    assert np.allclose(direct, 2.0, rtol=1e-6)
    lit = render(tmp_path, env, spp=256)
    const = render(tmp_path, '<emitter type="constant"><rgb name="radiance" value="2"/>'
                   '</emitter>', spp=256)
    np.testing.assert_allclose(mean(lit), RHO * 2.0, rtol=1e-2)
    np.testing.assert_allclose(mean(lit), mean(const), rtol=1e-2)


def _bilinear(im: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Mitsuba 3's envmap lookup (latitude-longitude, +y up), for reference values."""
    h, w = im.shape[:2]
    u = np.arctan2(v[..., 0], -v[..., 2]) / (2 * np.pi) - 0.5 / w
    u -= np.floor(u)
    x, y = u * w, np.arccos(np.clip(v[..., 1], -1, 1)) / np.pi * (h - 1)
    x0, y0 = np.minimum(x.astype(int), w - 1), np.minimum(y.astype(int), h - 2)
    x1, fx, fy = (x0 + 1) % w, (x - x0)[..., None], (y - y0)[..., None]
    top = im[y0, x0] * (1 - fx) + im[y0, x1] * fx
    return (top * (1 - fy) + (im[y0 + 1, x0] * (1 - fx) + im[y0 + 1, x1] * fx) * fy)


def test_envmap_lookup_follows_mitsubas_lat_long_layout(tmp_path):
    rng = np.random.default_rng(5)
    im = rng.uniform(0.1, 1.0, (9, 16, 3))
    # the camera looks along -z: between the last and the first column, halfway down
    img = render(tmp_path, _envmap(tmp_path, im), plane=False, res=1, fov=0.01)
    expected = _bilinear(im, np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(img[0, 0], expected, rtol=1e-3)


def test_diffuse_plane_under_a_varying_envmap(tmp_path):
    rng = np.random.default_rng(1)
    im = rng.uniform(0, 1, (16, 32, 3)) ** 4 * 5
    img = render(tmp_path, _envmap(tmp_path, im), spp=1024)
    # irradiance on the plane: midpoint quadrature in (cos theta, phi) of the bilinear map
    n = 1000
    z = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    radiance = _bilinear(im, np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1))
    irradiance = (radiance * zz[..., None]).mean(axis=(0, 1)) * 2 * np.pi
    np.testing.assert_allclose(mean(img), RHO / math.pi * irradiance, rtol=1e-2)


def test_envmap_from_png(tmp_path):
    pil = pytest.importorskip("PIL.Image")
    pil.fromarray(np.full((4, 8, 3), 128, np.uint8)).save(tmp_path / "env.png")
    img = render(tmp_path, f'<emitter type="envmap"><string name="filename" '
                 f'value="{tmp_path / "env.png"}"/></emitter>', plane=False)
    srgb = 128 / 255
    np.testing.assert_allclose(img, ((srgb + 0.055) / 1.055) ** 2.4, rtol=1e-5)


# ---- envmap importance sampling: samples against the pdf --------------------------------

SAMPLING_SRC = """
import emitter.envmap;
fn env(W: Int, H: Int) -> EnvMap {
    // to_world: 90 degrees about x (local +y up -> world +z)
    return EnvMap { width: W, height: H, scale: 1.0,
                    to_x: Vec3(1.0, 0.0, 0.0), to_y: Vec3(0.0, 0.0, -1.0),
                    to_z: Vec3(0.0, 1.0, 0.0), inv_x: Vec3(1.0, 0.0, 0.0),
                    inv_y: Vec3(0.0, 0.0, 1.0), inv_z: Vec3(0.0, -1.0, 0.0) };
}
fn sample(u: Vec2, W: Int, H: Int, ENV: [Float]) -> Vec4 {
    let ds = envmap_sample_direction(ENV, env(W, H), u);
    return Vec4(ds.d.x, ds.d.y, ds.d.z, ds.pdf);
}
fn sample_check(u: Vec2, W: Int, H: Int, ENV: [Float]) -> Vec2 {
    let m = env(W, H);
    let ds = envmap_sample_direction(ENV, m, u);
    let le = envmap_eval(ENV, m, ds.d);
    return Vec2(envmap_pdf_direction(ENV, m, ds.d) / ds.pdf, mean(le) / mean(ds.le));
}
fn pdf(d: Vec3, W: Int, H: Int, ENV: [Float]) -> Float {
    return envmap_pdf_direction(ENV, env(W, H), d);
}
"""


def test_envmap_sampling_matches_its_pdf():
    import rdsl
    from rdsl.runtime.render.emitters import envmap_tables

    rng = np.random.default_rng(11)
    im = rng.uniform(0, 1, (12, 20, 3)) ** 3
    im[3:5] *= 20.0  # a bright band
    im[8, 4:7] = 0.0
    table, (w, h) = envmap_tables(im)
    mod = rdsl.jit(SAMPLING_SRC)
    f32 = np.float32

    # the pdf integrates to one (midpoint rule in (z, phi): uniform in solid angle)
    nz, nphi = 400, 800
    z = (np.arange(nz) + 0.5) / nz * 2 - 1
    phi = (np.arange(nphi) + 0.5) / nphi * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    d = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3)
    p = np.asarray(mod["pdf"](d.astype(f32), w, h, table), np.float64).reshape(nz, nphi)
    assert abs(p.mean() * 4 * np.pi - 1.0) < 2e-3

    # samples: pdf and radiance agree with pdf_direction and eval
    n = 400_000
    u = rng.random((n, 2)).astype(f32)
    out = np.asarray(mod["sample"](u, w, h, table), np.float64)
    np.testing.assert_allclose(np.linalg.norm(out[:, :3], axis=1), 1.0, atol=1e-5)
    chk = np.asarray(mod["sample_check"](u[:20000], w, h, table), np.float64)
    assert np.mean(np.abs(chk[:, 0] - 1.0) < 1e-3) > 0.999
    assert np.mean(np.abs(chk[:, 1] - 1.0) < 1e-3) > 0.999

    # chi-square of a (z, phi) histogram against the pdf's integrals over its bins
    bz, bphi = 20, 40
    zi = np.minimum(((out[:, 2] + 1) / 2 * bz).astype(int), bz - 1)
    ph = np.mod(np.arctan2(out[:, 1], out[:, 0]), 2 * np.pi)
    pi_ = np.minimum((ph / (2 * np.pi) * bphi).astype(int), bphi - 1)
    observed = np.bincount(zi * bphi + pi_, minlength=bz * bphi).astype(np.float64)
    # every quadrature cell lies in exactly one bin (nz, nphi are multiples of bz, bphi)
    cell = p * (4 * np.pi / (nz * nphi))
    expected = cell.reshape(bz, nz // bz, bphi, nphi // bphi).sum(axis=(1, 3)).reshape(-1) * n
    keep = expected > 5
    assert observed[~keep].sum() <= max(5.0, 3 * expected[~keep].sum() + 5)
    chi2 = np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep])
    dof = keep.sum() - 1
    assert chi2 < dof + 5 * math.sqrt(2 * dof), (chi2, dof)


# ---- bad input --------------------------------------------------------------------------

@pytest.mark.parametrize("emitter, message", [
    ("""<emitter type="spot"><texture type="checkerboard" name="texture"/>
        <float name="cutoff_angle" value="100"/></emitter>""",
     "a projected 'texture' needs a 'cutoff_angle' below 90 degrees"),
    ("""<emitter type="spot"><float name="cutoff_angle" value="10"/>
        <float name="beam_width" value="20"/></emitter>""", "'beam_width'"),
    ("""<emitter type="point"><texture type="checkerboard" name="intensity"/></emitter>""",
     "'intensity': a texture is not supported"),
    ("""<emitter type="constant"/><emitter type="constant"/>""",
     "only one environment emitter"),
    ("""<emitter type="envmap"><string name="filename" value="{env}"/>
        <string name="filter_type" value="nearest"/></emitter>""", "filter_type 'nearest'"),
    ("""<emitter type="envmap"><string name="filename" value="{env}"/>
        <transform name="to_world"><scale value="2"/></transform></emitter>""",
     "must be a rotation"),
])
def test_unsupported_emitter_parameters_are_clear_errors(tmp_path, emitter, message):
    write_exr(tmp_path / "env.exr", np.ones((4, 8, 3), np.float32))
    path = tmp_path / "scene.xml"
    path.write_text(scene_xml(emitter.format(env=tmp_path / "env.exr")))
    with pytest.raises(CompileError, match=message):
        load_scene(path)
