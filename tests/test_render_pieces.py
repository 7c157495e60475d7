"""Renderer pieces: camera rays (stdlib/render/camera.rdsl), reconstruction filters and the
gather film (stdlib/render/film.rdsl), images and progress (rdsl.runtime.render).

The camera is checked against an independent numpy transcription of Mitsuba 3's
``perspective_projection`` / ``sample_ray``; the film against a literal numpy transcription
of Mitsuba 3's splatting ``ImageBlock::put`` on the same random samples.
"""

from __future__ import annotations

import io
import math
import struct
import zlib

import numpy as np
import pytest
import rdsl
from _scenes import CBOX
from rdsl.runtime.render import (
    Progress,
    camera_uniforms,
    develop,
    film_uniforms,
    new_accumulator,
    read_exr,
    read_exr_channels,
    rmse,
    summary_line,
    write_exr,
    write_png,
)
from rdsl.runtime.render.film import FILTERS, border_size, filter_radius
from rdsl.runtime.scene import load_scene_description

CBOX_REF = CBOX.with_name("cbox_ref_rgb.exr")
needs_cbox = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")

CAMERA_SRC = """
import render.camera;
fn ray(cam: Camera, uv: Vec2, a: Vec2) -> Ray { return camera_ray(cam, uv, a); }
fn ray_px(cam: Camera, p: Vec2, a: Vec2) -> Ray { return camera_ray_px(cam, p, a); }
"""

FILM_SRC = """
import render.film;
fn accumulate(pixel: Int, film: Film, pos: [Float], values: [Float], acc: [Float]) -> Int {
    return film_accumulate(pixel, film, pos, values, acc);
}
fn eval(kind: Int, x: Float, param: Float, param2: Float) -> Float {
    return filter_eval(kind, x, param, param2);
}
"""


@pytest.fixture(scope="module")
def cam_mod():
    return rdsl.jit(CAMERA_SRC, target="host")


@pytest.fixture(scope="module")
def film_mod():
    return rdsl.jit(FILM_SRC, target="host")


# -- an independent numpy Mitsuba 3 camera ------------------------------------------------

def mi_lookat(origin, target, up) -> np.ndarray:
    """Mitsuba's Transform4f::look_at: columns (left, up, dir, origin)."""
    origin, target, up = (np.asarray(v, np.float64) for v in (origin, target, up))
    d = (target - origin) / np.linalg.norm(target - origin)
    left = np.cross(up, d)
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, origin
    return m


def mi_sample_to_camera(size, crop_size, crop_offset, fov_x, near, far) -> np.ndarray:
    """inverse(perspective_projection(...)) of Mitsuba 3's sensor.h."""
    def scale(x, y, z):
        return np.diag([x, y, z, 1.0])

    def translate(x, y, z):
        m = np.eye(4)
        m[:3, 3] = (x, y, z)
        return m

    size = np.asarray(size, np.float64)
    rel_size = np.asarray(crop_size) / size
    rel_offset = np.asarray(crop_offset) / size
    aspect = size[0] / size[1]
    cot = 1.0 / math.tan(math.radians(fov_x) / 2)
    persp = np.diag([cot, cot, far / (far - near), 0.0])
    persp[2, 3] = -near * far / (far - near)
    persp[3, 2] = 1.0
    cam_to_sample = (scale(1 / rel_size[0], 1 / rel_size[1], 1)
                     @ translate(-rel_offset[0], -rel_offset[1], 0)
                     @ scale(-0.5, -0.5 * aspect, 1)
                     @ translate(-1, -1 / aspect, 0) @ persp)
    return np.linalg.inv(cam_to_sample)


def mi_disk_concentric(u: np.ndarray) -> np.ndarray:
    x, y = 2 * u[:, 0] - 1, 2 * u[:, 1] - 1
    q13 = np.abs(x) < np.abs(y)
    r = np.where(q13, y, x)
    rp = np.where(q13, x, y)
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = 0.25 * np.pi * rp / r
    phi = np.where(q13, 0.5 * np.pi - phi, phi)
    phi = np.where((x == 0) & (y == 0), 0.0, phi)
    return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)


def mi_sample_ray(sensor, to_world, uv, aperture_u):
    """Mitsuba 3's perspective/thinlens ``sample_ray`` for crop-relative ``uv``."""
    p, f = sensor.params, sensor.film
    s2c = mi_sample_to_camera((f["width"], f["height"]), (f["crop_width"], f["crop_height"]),
                              (f["crop_offset_x"], f["crop_offset_y"]), p["fov_x"],
                              p["near_clip"], p["far_clip"])
    ppo = np.array([p.get("principal_point_offset_x", 0.0) or 0.0,
                    p.get("principal_point_offset_y", 0.0) or 0.0])
    ppo_scaled = np.array([f["width"], f["height"]]) * ppo / [f["crop_width"], f["crop_height"]]
    pts = np.c_[uv + ppo_scaled, np.zeros(len(uv)), np.ones(len(uv))] @ s2c.T
    near_p = pts[:, :3] / pts[:, 3:]
    if sensor.type == "thinlens":
        ap = p["aperture_radius"] * mi_disk_concentric(aperture_u)
        ap = np.c_[ap, np.zeros(len(uv))]
        focus_p = near_p * (p["focus_distance"] / near_p[:, 2:])
        d = focus_p - ap
    else:
        ap = np.zeros((len(uv), 3))
        d = near_p
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    o = ap @ to_world[:3, :3].T + to_world[:3, 3]
    wd = d @ to_world[:3, :3].T
    near_t, far_t = p["near_clip"] / d[:, 2], p["far_clip"] / d[:, 2]
    return o + wd * near_t[:, None], wd, far_t - near_t


SENSOR_XML = """<scene version="3.0.0">
 <sensor type="{type}">
  <float name="fov" value="50"/><string name="fov_axis" value="{axis}"/>
  <float name="near_clip" value="0.01"/><float name="far_clip" value="50"/>
  {extra}
  <transform name="to_world"><lookat origin="1, 2, 3" target="0, 0.5, 0" up="0, 0, 1"/></transform>
  <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="30"/>
   <integer name="crop_offset_x" value="5"/><integer name="crop_width" value="20"/>
   <integer name="crop_offset_y" value="7"/><integer name="crop_height" value="10"/>
  </film>
 </sensor>
</scene>
"""

SENSORS = {
    "perspective": ("perspective", "y", ('<float name="principal_point_offset_x" value="0.05"/>'
                                         '<float name="principal_point_offset_y" value="-0.1"/>')),
    "perspective_diag": ("perspective", "diagonal", ""),
    "thinlens": ("thinlens", "x", ('<float name="aperture_radius" value="0.2"/>'
                                   '<float name="focus_distance" value="3.5"/>')),
}


def _ray_arrays(r):
    return r["o"].astype(np.float64), r["d"].astype(np.float64), r["tmax"].astype(np.float64)


@pytest.mark.parametrize("name", sorted(SENSORS))
def test_camera_matches_mitsuba_formula(cam_mod, tmp_path, name):
    kind, axis, extra = SENSORS[name]
    path = tmp_path / "scene.xml"
    path.write_text(SENSOR_XML.format(type=kind, axis=axis, extra=extra))
    sensor = load_scene_description(path).sensor
    to_world = mi_lookat((1, 2, 3), (0, 0.5, 0), (0, 0, 1))
    np.testing.assert_allclose(sensor["to_world"], to_world, atol=1e-12)
    rng = np.random.default_rng(1)
    uv = rng.random((257, 2))
    uv[:4] = [[0, 0], [1, 1], [0.5, 0.5], [0, 1]]
    au = rng.random((257, 2))
    cam = camera_uniforms(sensor)
    o, d, tmax = _ray_arrays(cam_mod["ray"](cam, uv.astype(np.float32), au.astype(np.float32)))
    o_ref, d_ref, tmax_ref = mi_sample_ray(sensor, to_world, uv, au)
    np.testing.assert_allclose(d, d_ref, atol=2e-6)
    np.testing.assert_allclose(o, o_ref, atol=2e-5)
    np.testing.assert_allclose(tmax, tmax_ref, rtol=2e-5)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    # the pixel-coordinate entry point: film pixel = crop offset + uv * crop size
    f = sensor.film
    px = uv * [f["crop_width"], f["crop_height"]] + [f["crop_offset_x"], f["crop_offset_y"]]
    o2, d2, _ = _ray_arrays(cam_mod["ray_px"](cam, px.astype(np.float32),
                                              au.astype(np.float32)))
    np.testing.assert_allclose(d2, d_ref, atol=2e-6)
    np.testing.assert_allclose(o2, o_ref, atol=2e-5)


def test_thinlens_rays_focus_on_the_focal_plane(cam_mod, tmp_path):
    kind, axis, extra = SENSORS["thinlens"]
    path = tmp_path / "scene.xml"
    path.write_text(SENSOR_XML.format(type=kind, axis=axis, extra=extra))
    sensor = load_scene_description(path).sensor
    cam = camera_uniforms(sensor)
    n = 64
    uv = np.tile(np.float32([[0.3, 0.7]]), (n, 1))
    au = np.random.default_rng(2).random((n, 2)).astype(np.float32)
    o, d, _ = _ray_arrays(cam_mod["ray"](cam, uv, au))
    axis_n, origin = np.array(cam["basis"]["n"]), np.array(cam["origin"])
    t = (3.5 - (o - origin) @ axis_n) / (d @ axis_n)
    hit = o + d * t[:, None]
    assert np.ptp(hit, axis=0).max() < 1e-4       # one point in focus
    assert np.ptp(o, axis=0).max() > 0.05         # from different lens positions


@needs_cbox
def test_cbox_camera_axis_fov_and_orientation(cam_mod):
    scene = load_scene_description(CBOX)
    sensor = scene.sensor
    cam = camera_uniforms(sensor)
    fov = math.radians(39.3077)   # fov_axis = smaller, square film: fov_x = fov_y = fov
    uv = np.float32([[0.5, 0.5], [0, 0.5], [1, 0.5], [0.5, 0], [0.5, 1], [0, 0], [1, 1]])
    o, d, _ = _ray_arrays(cam_mod["ray"](cam, uv, np.zeros_like(uv)))
    look = np.array([0, 0, -1.0])                  # lookat origin (0,0,3.9) -> target 0
    np.testing.assert_allclose(d[0], look, atol=1e-7)
    ang = np.degrees(np.arccos(np.clip(d @ look, -1, 1)))
    edge = math.degrees(fov / 2)
    corner = math.degrees(math.atan(math.sqrt(2) * math.tan(fov / 2)))
    np.testing.assert_allclose(ang[1:], [edge] * 4 + [corner] * 2, atol=1e-4)
    # Orientation.  Mitsuba's lookat puts camera +x at cross(up, dir) = world -x here, and
    # its projection maps the film's left edge (uv.x = 0) to camera +x; so image-left must
    # look toward world -x, image-top toward world +y.  The red wall is the rectangle at
    # x = -1: the ray at the middle of the left edge must hit it (inside the box) first.
    assert d[1, 0] < 0 < d[2, 0] and d[3, 1] > 0 > d[4, 1]
    red = next(s for s in scene.shapes if s.id == "red-wall")
    green = next(s for s in scene.shapes if s.id == "green-wall")
    assert np.allclose(red.mesh.vertices[:, 0], -1) and np.allclose(green.mesh.vertices[:, 0], 1)
    rgb = red.bsdf["reflectance"].rgb
    assert rgb[0] > 5 * rgb[1]
    u = np.float32([[0.02, 0.5], [0.98, 0.5]])
    o, d, _ = _ray_arrays(cam_mod["ray"](cam, u, np.zeros_like(u)))
    for k, wall_x in ((0, -1.0), (1, 1.0)):
        t = (wall_x - o[k, 0]) / d[k, 0]
        hit = o[k] + t * d[k]
        assert t > 0 and abs(hit[1]) < 1 and -1 < hit[2] < 1, hit
    # ... and Mitsuba's reference render indeed has the red wall on the left
    if CBOX_REF.is_file():
        ref = read_exr(CBOX_REF)
        left, right = ref[96:160, 2:10].mean((0, 1)), ref[96:160, -10:-2].mean((0, 1))
        assert left[0] > 3 * left[1] and right[1] > 1.5 * right[0]


# -- filters ---------------------------------------------------------------------------------

def np_filter(kind: str, x: np.ndarray, param: float, param2: float = 0.0) -> np.ndarray:
    """Mitsuba 3's rfilters, in float64 (mitchell: B = param, C = param2; lanczos: param
    lobes)."""
    if kind == "box":
        return np.where((x >= -0.5) & (x < 0.5), 1.0, 0.0)
    if kind == "tent":
        return np.maximum(0.0, 1.0 - np.abs(x / param))
    if kind in ("mitchell", "catmullrom"):
        b, c = (param, param2) if kind == "mitchell" else (0.0, 0.5)
        a = np.abs(x)
        inner = (12 - 9 * b - 6 * c) * a**3 + (-18 + 12 * b + 6 * c) * a**2 + (6 - 2 * b)
        outer = ((-b - 6 * c) * a**3 + (6 * b + 30 * c) * a**2 + (-12 * b - 48 * c) * a
                 + (8 * b + 24 * c))
        return np.where(a < 2, np.where(a < 1, inner, outer) / 6, 0.0)
    if kind == "lanczos":
        a = np.abs(np.asarray(x, np.float64))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.sinc(a) * np.sinc(a / param)
        return np.where(a > param, 0.0, r)
    alpha = -1.0 / (2 * param * param)
    return np.maximum(0.0, np.exp(alpha * x * x) - math.exp(alpha * (4 * param) ** 2))


FILTER_CASES = [("box", 0.5), ("tent", 1.0), ("tent", 1.7), ("gaussian", 0.5),
                ("gaussian", 0.8)]
# the filters with negative lobes: (kind, param, param2) as film.rdsl takes them
SIGNED_CASES = [("mitchell", 1 / 3, 1 / 3), ("mitchell", 0.2, 0.6), ("catmullrom", 0.0, 0.5),
                ("lanczos", 3, 0.0), ("lanczos", 2, 0.0)]


@pytest.mark.parametrize("kind,param", FILTER_CASES)
def test_filter_values_and_integral(film_mod, kind, param):
    radius = 0.5 if kind == "box" else (param if kind == "tent" else 4 * param)
    n = 200001
    x = np.linspace(-radius - 0.5, radius + 0.5, n)
    f = film_mod["eval"](FILTERS[kind], x.astype(np.float32), param, 0.0).astype(np.float64)
    np.testing.assert_allclose(f, np_filter(kind, x.astype(np.float32), param), atol=2e-7)
    assert f.min() >= 0 and np.all(f[np.abs(x) > radius] == 0)
    integral = np.sum(f) * (x[1] - x[0])
    if kind == "box":
        exact = 1.0
    elif kind == "tent":
        exact = param
    else:
        bias = math.exp(-8.0)
        exact = math.sqrt(2 * math.pi) * param * math.erf(2 * math.sqrt(2)) - 2 * radius * bias
    assert abs(integral - exact) < 1e-4 * exact
    # normalized, the filter is a unit-mass kernel (what the film's weight division relies on)
    assert abs(integral / exact - 1.0) < 1e-4


@pytest.mark.parametrize("kind,param,param2", SIGNED_CASES)
def test_signed_filter_values(film_mod, kind, param, param2):
    """Mitchell-Netravali (catmullrom: B = 0, C = 1/2) and Lanczos: their values, negative
    lobes and support; a Mitchell filter sums to 1 over integer shifts, whatever B and C."""
    radius = param if kind == "lanczos" else 2.0
    x = np.linspace(-radius - 0.5, radius + 0.5, 100001)
    f = film_mod["eval"](FILTERS[kind], x.astype(np.float32), param,
                         param2).astype(np.float64)
    np.testing.assert_allclose(f, np_filter(kind, x.astype(np.float32), param, param2),
                               atol=2e-6)
    assert f.min() < 0 and np.all(f[np.abs(x) > radius] == 0)
    assert film_mod["eval"](FILTERS[kind], np.float32([0.0]), param, param2)[0] == \
        pytest.approx(1.0 if kind != "mitchell" else 1 - param / 3, abs=1e-6)
    if kind != "lanczos":
        t = np.float32(0.3) + np.arange(-2, 3, dtype=np.float32)
        assert film_mod["eval"](FILTERS[kind], t, param, param2).sum() == \
            pytest.approx(1.0, abs=1e-6)


# -- the film --------------------------------------------------------------------------------

class _RFilter:
    def __init__(self, type_: str, **params: float) -> None:
        self.type, self.params = type_, params


class _FilmPlugin:
    def __init__(self, rfilter: _RFilter, sample_border: bool) -> None:
        self.params = {"width": 17, "height": 13, "crop_offset_x": 3, "crop_offset_y": 2,
                       "crop_width": 10, "crop_height": 7, "sample_border": sample_border,
                       "rfilter": rfilter}

    def __getitem__(self, k):
        return self.params[k]


def make_samples(film: dict, rng, nan_every: int = 0):
    gw, gh, spp, c = film["grid_w"], film["grid_h"], film["spp"], film["channels"]
    gx, gy = np.meshgrid(np.arange(gw), np.arange(gh))
    pix = np.stack([gx.ravel() + film["grid_x"], gy.ravel() + film["grid_y"]], axis=1)
    pos = (np.repeat(pix, spp, axis=0) + rng.random((gw * gh * spp, 2))).astype(np.float32)
    vals = rng.random((gw * gh * spp, c)).astype(np.float32) * 4
    if nan_every:
        bad = np.arange(0, len(vals), nan_every)
        vals[bad[::2], rng.integers(0, c)] = np.nan
        vals[bad[1::2], 0] = np.inf
    return pos, vals


def splat_reference(film: dict, rfilter: _RFilter, pos: np.ndarray, vals: np.ndarray):
    """Mitsuba 3 ImageBlock::put (non-coalesced path) + develop's weight channel, in float64,
    for a block at the crop window without border; non-finite samples are left out."""
    cw, ch, c = film["crop_w"], film["crop_h"], film["channels"]
    acc = np.zeros((ch, cw, c + 1))
    ok = np.all(np.isfinite(vals), axis=1) & np.all(np.isfinite(pos), axis=1)
    offset = np.array([film["crop_x"], film["crop_y"]])
    for p, v in zip(pos[ok].astype(np.float64), vals[ok].astype(np.float64)):
        vw = np.append(v, 1.0)
        if rfilter.type == "box":
            q = np.floor(p).astype(int) - offset
            if 0 <= q[0] < cw and 0 <= q[1] < ch:
                acc[q[1], q[0]] += vw
            continue
        r = filter_radius(rfilter)
        pf = p - offset - 0.5
        lo = np.maximum(np.ceil(pf - r).astype(int), 0)
        hi = np.minimum(np.floor(pf + r).astype(int), [cw - 1, ch - 1])
        param = rfilter.params.get("stddev", rfilter.params.get("radius"))
        param2 = 0.0
        if rfilter.type == "mitchell":
            param, param2 = rfilter.params.get("B", 1 / 3), rfilter.params.get("C", 1 / 3)
        elif rfilter.type == "lanczos":
            param = rfilter.params.get("lobes", 3)
        for qy in range(lo[1], hi[1] + 1):
            wy = np_filter(rfilter.type, np.float64(qy - pf[1]), param, param2)
            for qx in range(lo[0], hi[0] + 1):
                wx = np_filter(rfilter.type, np.float64(qx - pf[0]), param, param2)
                acc[qy, qx] += wx * wy * vw
    return acc


def run_film(film_mod, film, pos, vals, acc=None):
    acc = new_accumulator(film) if acc is None else acc
    pixels = np.arange(film["crop_w"] * film["crop_h"], dtype=np.int32)
    bad = film_mod["accumulate"](pixels, film, np.ascontiguousarray(pos.reshape(-1)),
                                 np.ascontiguousarray(vals.reshape(-1)), acc, threads=1)
    return acc, bad


FILM_CASES = [(_RFilter("box"), False), (_RFilter("tent", radius=1.0), False),
              (_RFilter("tent", radius=1.6), True), (_RFilter("gaussian", stddev=0.5), False),
              (_RFilter("gaussian", stddev=0.5), True), (_RFilter("mitchell"), False),
              (_RFilter("mitchell", B=0.2, C=0.6), True), (_RFilter("catmullrom"), False),
              (_RFilter("lanczos"), True), (_RFilter("lanczos", lobes=2), False)]


@pytest.mark.parametrize("rfilter,border", FILM_CASES,
                         ids=lambda v: getattr(v, "type", None) or str(v))
def test_film_gather_equals_splat(film_mod, rfilter, border):
    film = film_uniforms(_FilmPlugin(rfilter, border), spp=3)
    b = border_size(rfilter) if border else 0
    assert (film["grid_w"], film["grid_h"]) == (10 + 2 * b, 7 + 2 * b)
    rng = np.random.default_rng(7)
    pos, vals = make_samples(film, rng)
    acc, bad = run_film(film_mod, film, pos, vals)
    ref = splat_reference(film, rfilter, pos, vals)
    got = acc.reshape(ref.shape)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())
    assert not bad.any()
    img = develop(acc, film)
    assert img.shape == (7, 10, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img, ref[..., :3] / ref[..., 3:], rtol=2e-5)


def test_film_skips_and_counts_nonfinite_samples(film_mod):
    rf = _RFilter("gaussian", stddev=0.5)
    film = film_uniforms(_FilmPlugin(rf, False), spp=4)
    pos, vals = make_samples(film, np.random.default_rng(3), nan_every=5)
    pos[1] = [np.nan, 3.0]                       # a broken position is skipped too
    acc, bad = run_film(film_mod, film, pos, vals)
    ref = splat_reference(film, rf, pos, vals)
    np.testing.assert_allclose(acc.reshape(ref.shape), ref, rtol=1e-5,
                               atol=1e-5 * np.abs(ref).max())
    assert np.all(np.isfinite(acc))
    invalid = ~(np.all(np.isfinite(vals), axis=1) & np.all(np.isfinite(pos), axis=1))
    assert bad.sum() == invalid.sum() > 0
    np.testing.assert_array_equal(bad, invalid.reshape(-1, film["spp"]).sum(axis=1))


def test_film_accumulates_batches(film_mod):
    rf = _RFilter("tent", radius=1.0)
    film2 = film_uniforms(_FilmPlugin(rf, False), spp=2)
    film4 = dict(film2, spp=4)
    rng = np.random.default_rng(11)
    (pa, va), (pb, vb) = make_samples(film2, rng), make_samples(film2, rng)
    acc, _ = run_film(film_mod, film2, pa, va)
    acc, _ = run_film(film_mod, film2, pb, vb, acc)
    n = film2["grid_w"] * film2["grid_h"]
    both_p = np.concatenate([pa.reshape(n, 2, 2), pb.reshape(n, 2, 2)], axis=1)
    both_v = np.concatenate([va.reshape(n, 2, 3), vb.reshape(n, 2, 3)], axis=1)
    acc4, _ = run_film(film_mod, film4, both_p, both_v)
    np.testing.assert_allclose(acc, acc4, rtol=1e-5, atol=1e-6)


# -- images and progress ---------------------------------------------------------------------

def test_exr_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    img = (rng.random((9, 14, 3)) * 10).astype(np.float32)
    img[0, 0] = [0.0, 1e-8, 6e4]
    aov = rng.random((9, 14)).astype(np.float32)
    stokes = rng.random((9, 14, 4)).astype(np.float32)
    path = tmp_path / "x.exr"
    write_exr(path, img, extra={"depth": aov, "S": stokes})
    np.testing.assert_array_equal(read_exr(path), img)
    ch = read_exr_channels(path)
    assert set(ch) == {"R", "G", "B", "depth", "S.R", "S.G", "S.B", "S.A"}
    np.testing.assert_array_equal(ch["depth"], aov)
    np.testing.assert_array_equal(ch["S.A"], stokes[..., 3])
    assert rmse(read_exr(path), img) == 0.0
    assert rmse(np.zeros((2, 2)), np.ones((2, 2))) == 1.0


def _decode_png(data: bytes):
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    i, chunks = 8, []
    while i < len(data):
        (n,) = struct.unpack(">I", data[i:i + 4])
        kind, body = data[i + 4:i + 8], data[i + 8:i + 8 + n]
        (crc,) = struct.unpack(">I", data[i + 8 + n:i + 12 + n])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF
        chunks.append((kind, body))
        i += 12 + n
    assert chunks[0][0] == b"IHDR" and chunks[-1][0] == b"IEND"
    w, h, depth, ctype, _, _, _ = struct.unpack(">IIBBBBB", chunks[0][1])
    raw = zlib.decompress(b"".join(b for k, b in chunks if k == b"IDAT"))
    c = {0: 1, 2: 3, 6: 4}[ctype]
    rows = np.frombuffer(raw, np.uint8).reshape(h, 1 + w * c)
    assert depth == 8 and np.all(rows[:, 0] == 0)   # filter type 0 on every row
    return rows[:, 1:].reshape(h, w, c)


def test_png_srgb(tmp_path):
    img = np.zeros((5, 7, 3), np.float32)
    img[0, 0] = [0.0, 1.0, 2.0]                  # clamped
    img[1, 1] = [0.18, 0.0031308, 0.5]
    img[2, 2] = [np.nan, -1.0, np.inf]
    path = tmp_path / "x.png"
    write_png(path, img)
    px = _decode_png(path.read_bytes())
    assert px.shape == (5, 7, 3)
    assert list(px[0, 0]) == [0, 255, 255]
    def srgb(x):
        return x * 12.92 if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055
    assert list(px[1, 1]) == [round(255 * srgb(v)) for v in (0.18, 0.0031308, 0.5)]
    assert list(px[2, 2]) == [0, 0, 255]
    write_png(path, np.full((3, 4), 0.5, np.float32))
    assert _decode_png(path.read_bytes()).shape == (3, 4, 1)


def test_progress_plain_and_forced():
    out = io.StringIO()
    with Progress(100, label="Rendering", stream=out) as p:
        for _ in range(100):
            p.advance(1)
    lines = out.getvalue().splitlines()
    assert 2 <= len(lines) <= 6 and lines[-1].startswith("Rendering 100%")
    out = io.StringIO()
    with Progress(10, stream=out, force=True, min_interval=0.0) as p:
        p.update(5)
        p.update(10)
    text = out.getvalue()
    assert "\r" in text and "[" in text and text.endswith("\n") and "100%" in text
    silent = io.StringIO()
    Progress(3, stream=silent, enabled=False).finish()
    assert silent.getvalue() == ""
    line = summary_line("render", 2.0, 4e6, extra="3 NaN samples")
    assert line == "render: 2.00 s (2.00 M samples/s), 3 NaN samples"
