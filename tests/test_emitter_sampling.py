"""Emitter sampling (stdlib/render/lights.rdsl `sample_emitter`) against closed forms.

One scene holds every kind of emitter but the envmap (tested in test_emitters.py): area
lights on a rectangle (triangles), an analytic sphere and an analytic disk, and point, spot,
directional and constant emitters.  At a point p with normal +z, for each emitter (told apart
by the uniform emitter choice, as the integrator makes it):

- the estimator le * cos / pdf averages to the closed-form irradiance (Lambert's polygon
  formula, pi L (R/d)^2 cos for a sphere, pi L R^2 / (h^2 + R^2) on a disk's axis,
  I cos / r^2 for point and spot, E cos for directional, pi L for the sky);
- where the pdf is a density, the sampled directions pass a chi-square test against the pdf
  computed here in numpy from the emitter's geometry (area sampling: dist^2 / (cos A); the
  sphere, seen from outside, is sampled uniformly over the cone it subtends, as in Mitsuba 3:
  1 / (2 pi (1 - cos theta_max)); the sky: 1 / 4 pi), and the pdf the integrator evaluates when a ray hits the emitter
  (`area_emitter_pdf`, `environment_pdf`, used for MIS) equals the pdf of the sample.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import rdsl

pytest.importorskip("rdsl.runtime.embree")

from rdsl.core.scene_spec import SceneSpec  # noqa: E402
from rdsl.runtime.render.renderer import load_scene  # noqa: E402

SRC = """
import render.lights;
import emitter.area;
struct Est { d: Vec3, e: Float, pdf: Float, pdf_hit: Float, geom: Int, valid: Bool }
fn estimate(p: Vec3, u: Vec2, upick: Float, nemitter: Int, env: Int, P: [Float], N: [Float],
            UV: [Float], F: [Int], G: [Int], LC: [Float], LT: [Int], T: [Float], EK: [Int],
            E: [Float], ENV: [Float]) -> Est {
    let n = Vec3(0.0, 0.0, 1.0);
    let ls = sample_emitter(p, n, u, upick, nemitter, P, UV, F, G, LC, LT, T, EK, E, ENV);
    if !ls.valid || !(ls.pdf > 0.0) {
        return Est { d: Vec3(0.0), e: 0.0, pdf: 0.0, pdf_hit: 0.0, geom: -1, valid: false };
    }
    let d = ls.ray.d;
    // the pdf the integrator gives this direction when a ray finds the emitter (MIS)
    var pdf_hit = 0.0;
    var geom = -1;
    if !ls.delta {
        let ray = Ray { o: ls.ray.o, d: d, tmax: infinity() };  // the shadow ray, unbounded
        let h = trace(ray);
        if h.valid {
            geom = h.geom;
            let it = interaction(ray, h, P, N, UV, F, G);
            if it.emitter >= 0 {
                pdf_hit = area_emitter_pdf(it.emitter, ray.o, h.t, it.si.wi, nemitter, P, EK, E);
            }
        } else if env >= 0 {
            pdf_hit = environment_pdf(env, d, nemitter, EK, E, ENV);
        }
    }
    return Est { d: d, e: mean(ls.le) * max(dot(d, n), 0.0) / ls.pdf, pdf: ls.pdf,
                 pdf_hit: pdf_hit, geom: geom, valid: true };
}
"""

BLACK = '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'
RECT_TO_WORLD = """<scale x="0.5" y="0.3"/><rotate x="1" angle="180"/><rotate z="1" angle="25"/>
    <translate x="0.4" y="-0.3" z="1.2"/>"""
SPHERE_C, SPHERE_R = np.array([-0.8, 0.5, 2.0]), 0.4
DISK_R, DISK_H = 0.5, 1.3
SPOT_O = np.array([-0.2, 0.1, 1.5])
POINT = np.array([0.3, 0.2, 2.0])
DIRECTION = np.array([0.3, 0.0, -1.0])
L_RECT, L_SPHERE, L_DISK, I_POINT, I_SPOT, E_DIR, L_SKY = 3.0, 5.0, 2.0, 4.0, 6.0, 1.5, 0.7

SCENE = f"""<scene version="3.0.0">
  <shape type="rectangle"><transform name="to_world">{RECT_TO_WORLD}</transform>{BLACK}
    <emitter type="area"><rgb name="radiance" value="{L_RECT}"/></emitter></shape>
  <shape type="sphere"><point name="center" x="{SPHERE_C[0]}" y="{SPHERE_C[1]}"
    z="{SPHERE_C[2]}"/><float name="radius" value="{SPHERE_R}"/>{BLACK}
    <emitter type="area"><rgb name="radiance" value="{L_SPHERE}"/></emitter></shape>
  <shape type="disk"><transform name="to_world"><scale value="{DISK_R}"/>
    <rotate x="1" angle="180"/><translate z="{DISK_H}"/></transform>{BLACK}
    <emitter type="area"><rgb name="radiance" value="{L_DISK}"/></emitter></shape>
  <emitter type="point"><point name="position" x="{POINT[0]}" y="{POINT[1]}" z="{POINT[2]}"/>
    <rgb name="intensity" value="{I_POINT}"/></emitter>
  <emitter type="spot"><rgb name="intensity" value="{I_SPOT}"/>
    <float name="cutoff_angle" value="30"/><float name="beam_width" value="20"/>
    <transform name="to_world"><lookat origin="{SPOT_O[0]}, {SPOT_O[1]}, {SPOT_O[2]}"
      target="0, 0, 0"/></transform></emitter>
  <emitter type="directional"><vector name="direction" x="{DIRECTION[0]}" y="{DIRECTION[1]}"
    z="{DIRECTION[2]}"/><rgb name="irradiance" value="{E_DIR}"/></emitter>
  <emitter type="constant"><rgb name="radiance" value="{L_SKY}"/></emitter>
</scene>"""
NAMES = ["rectangle", "sphere", "disk", "point", "spot", "directional", "constant"]
N_PER = 200_000


def rect_corners(scene) -> np.ndarray:
    m = scene.desc.shapes[0].params["to_world"]
    local = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]], float)
    return (local @ m.T)[:, :3]


def polygon_irradiance(corners: np.ndarray, radiance: float) -> float:
    """Lambert's formula: irradiance at the origin (normal +z) from a uniform polygon."""
    v = corners / np.linalg.norm(corners, axis=1, keepdims=True)
    total = 0.0
    for i in range(len(v)):
        a, b = v[i], v[(i + 1) % len(v)]
        c = np.cross(a, b)
        total += math.acos(np.clip(a @ b, -1, 1)) * c[2] / np.linalg.norm(c)
    return 0.5 * radiance * abs(total)


def closed_forms(scene) -> dict[str, float]:
    dc = np.linalg.norm(SPHERE_C)
    spot_r = np.linalg.norm(SPOT_O)
    return {
        "rectangle": polygon_irradiance(rect_corners(scene), L_RECT),
        "sphere": math.pi * L_SPHERE * (SPHERE_R / dc) ** 2 * SPHERE_C[2] / dc,
        "disk": math.pi * L_DISK * DISK_R ** 2 / (DISK_H ** 2 + DISK_R ** 2),
        "point": I_POINT * POINT[2] / np.linalg.norm(POINT) ** 3,
        "spot": I_SPOT * SPOT_O[2] / spot_r ** 3,  # p is on the spot's axis: full intensity
        "directional": E_DIR * -DIRECTION[2] / np.linalg.norm(DIRECTION),
        "constant": math.pi * L_SKY,
    }


# ---- analytic pdfs (solid angle, given the emitter was chosen) ------------------------------

# the shadow ray starts off p = 0 along its normal +z (stdlib/render/geometry.rdsl spawn_ray_to)
ORIGIN = np.array([0.0, 0.0, 8.940697e-05])


def pdf_rectangle(scene, w: np.ndarray) -> np.ndarray:
    c = rect_corners(scene) - ORIGIN
    e1, e2 = c[1] - c[0], c[3] - c[0]
    nrm = np.cross(e1, e2)
    area = np.linalg.norm(nrm)
    nrm /= area
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (c[0] @ nrm) / (w @ nrm)
    y = w * t[:, None] - c[0]
    a, b = y @ e1 / (e1 @ e1), y @ e2 / (e2 @ e2)
    inside = (t > 0) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
    cos_l = np.abs(w @ nrm)
    return np.where(inside, t * t / (cos_l * area), 0.0), cos_l


def sphere_cone() -> tuple[np.ndarray, float, float]:
    """The cone of directions from p = 0 to the sphere: axis, cos theta_max, uniform pdf."""
    dc = np.linalg.norm(SPHERE_C)
    cos_max = math.sqrt(1 - (SPHERE_R / dc) ** 2)
    return SPHERE_C / dc, cos_max, 1 / (2 * math.pi * (1 - cos_max))


def pdf_sphere(w: np.ndarray) -> np.ndarray:
    axis, cos_max, pdf = sphere_cone()
    return np.where(w @ axis >= cos_max - 1e-6, pdf, 0.0), np.ones(len(w))


def cone_quadrature(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Directions of equal solid angle filling the sphere's cone, and their mass."""
    axis, cos_max, _ = sphere_cone()
    z = cos_max + (np.arange(n) + 0.5) / n * (1 - cos_max)
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    local = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3)
    w = local @ cap_frame(axis)
    return w, np.full(len(w), 1.0 / len(w))


def pdf_disk(w: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (DISK_H - ORIGIN[2]) / w[:, 2]
    r2 = (w[:, 0] * t) ** 2 + (w[:, 1] * t) ** 2
    area = math.pi * DISK_R ** 2
    cos_l = np.abs(w[:, 2])
    return np.where((t > 0) & (r2 <= DISK_R ** 2), t * t / (cos_l * area), 0.0), cos_l


def cap_frame(axis: np.ndarray) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    t = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(a, t), a])  # rows: s, t, axis


def sky_quadrature(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Directions of an (z, phi) grid over the sphere and their mass under the pdf 1/4pi."""
    z = (np.arange(n) + 0.5) / n * 2 - 1
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz * zz)
    w = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1).reshape(-1, 3)
    return w, np.full(len(w), 1.0 / len(w))


def surface_quadrature(points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions from p = 0 to equal-area surface points and their mass under uniform area
    sampling (1 / count each); points facing away from p are rejected samples (no mass).
    Integrating the solid-angle pdf dist^2 / (cos A) over a bin of directions is integrating
    1 / A over the surface seen through it: this form has no singularity at silhouettes."""
    facing = np.sum(normals * -points, 1) > 0
    w = points / np.linalg.norm(points, axis=1, keepdims=True)
    return w[facing], np.full(int(facing.sum()), 1.0 / len(points))


def disk_points(n: int = 800) -> tuple[np.ndarray, np.ndarray]:
    r = DISK_R * np.sqrt((np.arange(n) + 0.5) / n)  # equal-area rings
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    rr, pp = np.meshgrid(r, phi, indexing="ij")
    y = np.stack([rr * np.cos(pp), rr * np.sin(pp), np.full_like(rr, DISK_H)], -1)
    y = y.reshape(-1, 3)
    return y, np.tile([0.0, 0.0, -1.0], (len(y), 1))


def rect_points(scene, n: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    c = rect_corners(scene)
    a = (np.arange(n) + 0.5) / n
    aa, bb = np.meshgrid(a, a, indexing="ij")
    y = c[0] + aa.reshape(-1, 1) * (c[1] - c[0]) + bb.reshape(-1, 1) * (c[3] - c[0])
    nrm = np.cross(c[1] - c[0], c[3] - c[0])
    return y, np.tile(nrm / np.linalg.norm(nrm), (len(y), 1))


def chi_square(dirs: np.ndarray, n_drawn: int, quad: tuple[np.ndarray, np.ndarray],
               axis: np.ndarray, bins: tuple[int, int] = (10, 16),
               cos_min: float | None = None) -> tuple[float, int]:
    """Chi-square of the sampled directions in (cos alpha, phi) bins of the cap around
    ``axis`` that holds every quadrature direction, against ``n_drawn`` times the mass of the
    quadrature directions (``quad``: directions and masses) in each bin."""
    frame = cap_frame(axis)
    qw, qm = quad
    if cos_min is None:
        cos_min = float((qw @ frame.T)[:, 2].min()) - 1e-6

    def bin_of(w: np.ndarray) -> np.ndarray:
        loc = w @ frame.T
        ca = (loc[:, 2] - cos_min) / (1 - cos_min)
        ph = np.mod(np.arctan2(loc[:, 1], loc[:, 0]), 2 * np.pi) / (2 * np.pi)
        ic = np.clip((ca * bins[0]).astype(int), 0, bins[0] - 1)
        ip = np.minimum((ph * bins[1]).astype(int), bins[1] - 1)
        return ic * bins[1] + ip

    nb = bins[0] * bins[1]
    loc = dirs @ frame.T
    assert loc[:, 2].min() >= cos_min - 1e-4, "a sample outside the directions of the emitter"
    observed = np.bincount(bin_of(dirs), minlength=nb).astype(float)
    expected = np.bincount(bin_of(qw), weights=qm, minlength=nb) * n_drawn
    keep = expected > 5
    assert observed[~keep].sum() <= 3 * expected[~keep].sum() + 10
    chi2 = float(np.sum((observed[keep] - expected[keep]) ** 2 / expected[keep]))
    return chi2, int(keep.sum())


@pytest.fixture(scope="module")
def sampled(tmp_path_factory):
    path = tmp_path_factory.mktemp("emitters") / "emitters.xml"
    path.write_text(SCENE)
    scene = load_scene(path)
    b, lights = scene.buffers, scene.buffers.lights
    assert lights.nemitter == len(NAMES)
    mod = rdsl.jit(SRC, scene=SceneSpec(emitters=scene.emitters))  # no BSDF is needed
    mod.bind_scene(scene.embree)
    n = N_PER * len(NAMES)
    rng = np.random.default_rng(17)
    u = rng.random((n, 2)).astype(np.float32)
    upick = rng.random(n).astype(np.float32)
    out = mod.estimate(np.zeros((n, 3), np.float32), u, upick, lights.nemitter, lights.env, b.P,
                       b.N, b.UV, b.F, b.G, lights.LC, lights.LT, b.T, *lights.args())
    # which emitter each sample chose, as sample_emitter computes it (in float32)
    k = np.minimum((upick * np.float32(len(NAMES))).astype(int), len(NAMES) - 1)
    return scene, {key: np.asarray(v) for key, v in out.items()}, k


@pytest.mark.parametrize("name", NAMES)
def test_irradiance_matches_closed_form(sampled, name):
    scene, out, k = sampled
    i = NAMES.index(name)
    mine = k == i
    e = out["e"][mine].astype(np.float64) / len(NAMES)  # the pdf includes the 1/7 choice
    expected = closed_forms(scene)[name]
    err = abs(e.mean() - expected)
    sigma = e.std() / math.sqrt(len(e))
    # delta lights are exact; sampled ones within 4 standard errors (and 1 %)
    assert err < max(4 * sigma, 1e-5 * expected) and err < 1e-2 * expected, \
        (name, e.mean(), expected, sigma)


@pytest.mark.parametrize("name", ["rectangle", "sphere", "disk", "constant"])
def test_sampled_directions_follow_the_pdf(sampled, name):
    scene, out, k = sampled
    i = NAMES.index(name)
    mine = k == i
    valid = mine & out["valid"]
    d = out["d"][valid].astype(np.float64)
    if name == "constant":
        quad, axis = sky_quadrature(), np.array([0.0, 0.0, 1.0])
        own = valid & (out["geom"] < 0)  # rays that reach the sky
        pdf, cos_l = np.full(int(own.sum()), 1 / (4 * math.pi)), np.ones(int(own.sum()))
    else:
        if name == "sphere":
            quad, axis = cone_quadrature(), sphere_cone()[0]
        else:
            points = {"disk": disk_points, "rectangle": lambda: rect_points(scene)}[name]()
            quad, axis = surface_quadrature(*points), points[0].mean(axis=0)
        own = valid & (out["geom"] == i)  # the emitter's shape has geometry id i
        w = out["d"][own].astype(np.float64)
        pdf, cos_l = {"sphere": pdf_sphere, "disk": pdf_disk,
                      "rectangle": lambda w: pdf_rectangle(scene, w)}[name](w)
    chi2, bins = chi_square(d, int(mine.sum()), quad, axis,
                            cos_min=-1.0 if name == "constant" else None)
    dof = bins - 1
    assert chi2 < dof + 5 * math.sqrt(2 * dof), (name, chi2, dof)
    assert own.sum() > 0.3 * valid.sum(), (own.sum(), valid.sum())  # the rest is occluded
    # the sample's pdf is the analytic one (times the 1/7 emitter choice), and the pdf the
    # integrator gives the direction when a ray hits the emitter (for MIS) is the same; near
    # a sphere's silhouette (cos_l -> 0) float32 rounding of the point is amplified by
    # 1 / cos_l^2, so the comparison is tight where the geometry is well conditioned
    sharp = cos_l > 0.1
    assert sharp.mean() > 0.8
    for got, ref in ((out["pdf"][own] * len(NAMES), pdf),
                     (out["pdf_hit"][own], out["pdf"][own])):
        with np.errstate(divide="ignore", invalid="ignore"):  # 0 at a silhouette
            rel = np.abs(got / ref - 1)
        assert np.mean(rel[sharp] < 1e-3) > 0.999, (name, np.percentile(rel, [50, 99.9]))
        assert np.mean(rel < 2e-2) > 0.99, (name, np.percentile(rel, [50, 99]))


def test_delta_lights_are_flagged_and_exact(sampled):
    _, out, k = sampled
    for name in ("point", "spot", "directional"):
        mine = k == NAMES.index(name)
        assert np.all(out["valid"][mine]) and np.all(out["pdf_hit"][mine] == 0)
        e = out["e"][mine]
        assert np.ptp(e) <= 1e-6 * np.abs(e).max()  # no randomness at all
