"""Analytic spheres and disks: Embree user geometry with native callbacks.

- hits (distance, shape, a disk's local coordinates) from compiled `trace`/`occluded` on
  every target agree with an independent float64 ray-quadric intersector;
- the renderer's surface interaction on them (point, normal, uv, flip_normals, to_world with
  rotation and non-uniform scale) is Mitsuba's, computed here in numpy;
- a diffuse sphere and disk under a constant environment render to reflectance x radiance;
- an emissive sphere and disk light a diffuse plane with the closed-form irradiance;
- `triangulate` (shape option, or for the whole scene) gives the mesh instead.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.targets import get_target, host_supports
from rdsl.core.embree_abi import WIDTHS

embree = pytest.importorskip("rdsl.runtime.embree")
try:
    embree.load_embree()
except Exception as e:  # pragma: no cover - depends on the machine
    pytest.skip(f"Embree is not available: {e}", allow_module_level=True)

from rdsl.runtime import embree_user  # noqa: E402
from rdsl.runtime.render.renderer import load_scene  # noqa: E402

TARGETS = [t for t in ("scalar", "sse4", "avx2", "avx512") if host_supports(get_target(t))]

HIT_SRC = """
fn hit(o: Vec3, d: Vec3, tmax: Float) -> Vec4 {
    let h = trace(Ray { o: o, d: d, tmax: tmax });
    if !h.valid { return Vec4(-1.0); }
    return Vec4(h.t, Float(h.geom), h.u, h.v);
}
fn blocked(o: Vec3, d: Vec3, tmax: Float) -> Bool {
    return occluded(Ray { o: o, d: d, tmax: tmax });
}
"""


def rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m = np.eye(4)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def affine(lin: np.ndarray, t: tuple[float, float, float]) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = lin, t
    return m


SPHERES = [((0.3, -0.2, 0.1), 0.6), ((-1.2, 0.9, -0.4), 0.35)]
DISKS = [affine(np.diag([0.7, 0.7, 1.0]), (1.1, 0.2, 0.3)) @ rot("x", 35),
         affine((rot("y", 50) @ rot("z", 20))[:3, :3] @ np.diag([1.3, 0.4, 2.0]),
                (-0.5, -1.0, 0.6))]


def brute_force(o: np.ndarray, d: np.ndarray, tmax: np.ndarray):
    """Closest hit per ray in float64: t (inf on a miss), shape index, the disk's local
    (x, y), and a mask of rays that graze a silhouette or rim (left out of the comparison)."""
    o, d = o.astype(np.float64), d.astype(np.float64)
    n = len(o)
    ts, uvs, edge = [], [], np.zeros(n, bool)
    for c, r in SPHERES:
        oc = o - c
        a, b, cc = np.sum(d * d, 1), 2 * np.sum(oc * d, 1), np.sum(oc * oc, 1) - r * r
        disc = b * b - 4 * a * cc
        root = np.sqrt(np.maximum(disc, 0))
        near, far = (-b - root) / (2 * a), (-b + root) / (2 * a)
        t = np.where(near >= 0, near, far)
        ok = (disc >= 0) & (t >= 0) & (t <= tmax)
        edge |= np.abs(disc) < 1e-4 * a * r * r  # tangent rays
        ts.append(np.where(ok, t, np.inf))
        uvs.append(np.zeros((n, 2)))
    for m in DISKS:
        inv = np.linalg.inv(m)
        lo = o @ inv[:3, :3].T + inv[:3, 3]
        ld = d @ inv[:3, :3].T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -lo[:, 2] / ld[:, 2]
        xy = lo[:, :2] + ld[:, :2] * t[:, None]
        r2 = np.sum(xy * xy, 1)
        ok = (r2 <= 1) & (t >= 0) & (t <= tmax)
        edge |= np.abs(r2 - 1) < 1e-4
        ts.append(np.where(ok, t, np.inf))
        uvs.append(xy)
    t = np.stack(ts, 1)
    best = np.argmin(t, 1)
    rows = np.arange(n)
    tb = t[rows, best]
    srt = np.sort(t, 1)
    with np.errstate(invalid="ignore"):
        edge |= np.abs(srt[:, 0] - srt[:, 1]) < 1e-4  # two shapes nearly tied
        edge |= np.abs(tb - tmax) < 1e-4 * np.maximum(tmax, 1)  # hit right at tmax
    return tb, np.where(np.isfinite(tb), best, -1), np.stack(uvs, 1)[rows, best], edge


def random_rays(n: int, seed: int):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-3, 3, (n, 3)).astype(np.float32)
    d = (rng.uniform(-1.2, 1.2, (n, 3)) - o).astype(np.float32)
    d *= rng.uniform(0.5, 2.0, (n, 1)).astype(np.float32)  # not unit length
    tmax = np.where(rng.random(n) < 0.25, rng.uniform(0.1, 1.0, n), np.inf).astype(np.float32)
    return o, d, tmax


def user_scene():
    shapes = [embree_user.sphere(c, r) for c, r in SPHERES]
    shapes += [embree_user.disk(m) for m in DISKS]
    return embree.EmbreeScene(shapes)


@pytest.fixture(scope="module")
def hit_modules():
    return {t: rdsl.jit(HIT_SRC, target=t) for t in TARGETS}


def test_compiled_trace_matches_analytic_intersection_on_every_target(hit_modules):
    scene = user_scene()
    o, d, tmax = random_rays(3001, 7)  # not a multiple of any width
    t_ref, shape_ref, uv_ref, edge = brute_force(o, d, tmax.astype(np.float64))
    clear = ~edge
    hits = np.isfinite(t_ref)
    assert 0.3 < hits.mean() < 0.8 and set(shape_ref[hits]) == {0, 1, 2, 3}
    for target, mod in hit_modules.items():
        mod.bind_scene(scene)
        out = np.asarray(mod.hit(o, d, tmax), np.float64)
        got = out[:, 0] >= 0
        assert np.array_equal(got[clear], hits[clear]), target
        both = got & hits & clear
        rel = np.abs(out[both, 0] - t_ref[both]) / t_ref[both]
        assert rel.max() < 2.4e-7, (target, rel.max())  # float32 rounding of t (2 ulp)
        assert np.array_equal(out[both, 1].astype(int), shape_ref[both]), target
        disk = both & (shape_ref >= len(SPHERES))
        np.testing.assert_allclose(out[disk, 2:4], uv_ref[disk], atol=2.4e-7, err_msg=target)
        blocked = mod.blocked(o, d, tmax)
        assert np.array_equal(blocked[clear], hits[clear]), target


@pytest.mark.parametrize("width", WIDTHS)
def test_packet_widths_and_tmin(width):
    scene = user_scene()
    o, d, _ = random_rays(500, 3)
    tmin = np.float32(0.2)
    ref = scene.intersect(o, d, tmin=tmin, width=1)
    got = scene.intersect(o, d, tmin=tmin, width=width)
    for k in ("hit", "t", "geom_id", "u", "v"):
        np.testing.assert_array_equal(got[k], ref[k])
    t_ref, _, _, edge = brute_force(o + tmin * d, d, np.full(len(o), np.inf))
    ok = ~edge & np.isfinite(t_ref)
    np.testing.assert_allclose(got["t"][ok], t_ref[ok] + tmin, rtol=2e-6)
    assert np.array_equal(scene.occluded(o, d, tmin=tmin, width=width), ref["hit"])


def test_bad_user_shapes():
    with pytest.raises(ValueError, match="radius"):
        embree_user.sphere((0, 0, 0), -1.0)
    with pytest.raises(ValueError, match="center"):
        embree_user.sphere((0, np.nan, 0), 1.0)
    with pytest.raises(ValueError, match="singular"):
        embree_user.disk(np.diag([1.0, 0.0, 1.0, 1.0]))


# ---- the renderer's surface interaction ------------------------------------------------

INTERACTION_SRC = """
import render.geometry;
struct Probe { p: Vec3, n: Vec3, sh_n: Vec3, uv: Vec2, geom: Int, t: Float }
fn probe(o: Vec3, d: Vec3, P: [Float], N: [Float], UV: [Float], F: [Int], G: [Int]) -> Probe {
    let ray = Ray { o: o, d: d, tmax: infinity() };
    let h = trace(ray);
    if !h.valid {
        return Probe { p: Vec3(0.0), n: Vec3(0.0), sh_n: Vec3(0.0), uv: Vec2(0.0, 0.0),
                       geom: -1, t: 0.0 };
    }
    let it = interaction(ray, h, P, N, UV, F, G);
    return Probe { p: it.si.p, n: it.ng, sh_n: it.frame.n, uv: it.si.uv, geom: h.geom,
                   t: h.t };
}
"""

SHAPES_XML = """<scene version="3.0.0">
  <shape type="sphere"><point name="center" x="0.2" y="-0.1" z="0.3"/>
    <float name="radius" value="0.7"/>
    <transform name="to_world"><rotate x="1" y="1" z="0" angle="40"/></transform></shape>
  <shape type="sphere"><point name="center" x="0" y="2" z="0"/><float name="radius" value="0.4"/>
    <boolean name="flip_normals" value="true"/></shape>
  <shape type="disk"><boolean name="flip_normals" value="{flip}"/>
    <transform name="to_world"><scale x="0.8" y="0.5" z="3"/><rotate z="1" angle="30"/>
      <rotate x="1" angle="-70"/><translate x="-1.5" y="-1" z="0.2"/></transform></shape>
</scene>"""


def mitsuba_sphere(p: np.ndarray, center, radius, to_world: np.ndarray, flip: bool):
    """Mitsuba's sphere interaction at (near) surface points p: point, normal, uv."""
    n = (p - center) / np.linalg.norm(p - center, axis=1, keepdims=True)
    q = center + radius * n
    inv = np.linalg.inv(to_world)
    local = q @ inv[:3, :3].T + inv[:3, 3]
    local /= np.linalg.norm(local, axis=1, keepdims=True)
    phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi)
    theta = np.arccos(np.clip(local[:, 2], -1, 1))
    return q, -n if flip else n, np.stack([phi / (2 * np.pi), theta / np.pi], 1)


def mitsuba_disk(p: np.ndarray, to_world: np.ndarray, flip: bool):
    inv = np.linalg.inv(to_world)
    local = p @ inv[:3, :3].T + inv[:3, 3]
    n = np.linalg.inv(to_world[:3, :3]).T @ [0, 0, 1]
    n /= np.linalg.norm(n)
    r = np.linalg.norm(local[:, :2], axis=1)
    v = np.mod(np.arctan2(local[:, 1], local[:, 0]) / (2 * np.pi), 1.0)
    return np.broadcast_to(-n if flip else n, p.shape), np.stack([r, v], 1)


@pytest.mark.parametrize("flip", [False, True])
def test_interaction_is_mitsubas_analytic_surface(tmp_path, flip):
    path = tmp_path / "shapes.xml"
    path.write_text(SHAPES_XML.format(flip=str(flip).lower()))
    scene = load_scene(path)
    b = scene.buffers
    assert len(b.F) == 1 and scene.embree.counts == [(0, 0)] * 3  # no triangles at all
    desc = scene.desc.shapes
    rng = np.random.default_rng(5)
    n = 2000
    # rays from random points towards random points of the shapes' bounding regions
    aim = rng.integers(0, 3, n)
    centers = np.array([[0.2, -0.1, 0.3], [0, 2, 0], [-1.5, -1, 0.2]])
    target = centers[aim] + rng.normal(0, 0.35, (n, 3))
    o = target + rng.normal(0, 1, (n, 3)) * 2.5
    d = (target - o) / np.linalg.norm(target - o, axis=1, keepdims=True)
    o, d = o.astype(np.float32), d.astype(np.float32)
    for target_name in TARGETS:
        mod = rdsl.jit(INTERACTION_SRC, target=target_name)
        mod.bind_scene(scene.embree)
        out = mod.probe(o, d, b.P, b.N, b.UV, b.F, b.G)
        geom = np.asarray(out["geom"])
        assert {0, 1, 2} <= set(geom.tolist())
        p, ng, sh, uv = (np.asarray(out[k], np.float64) for k in ("p", "n", "sh_n", "uv"))
        np.testing.assert_array_equal(ng, sh)  # no shading normals on analytic shapes
        for k in (0, 1):
            s = geom == k
            a = desc[k].analytic
            q, nn, uvr = mitsuba_sphere(p[s], a.center, a.radius, a.to_world, a.flipped)
            np.testing.assert_allclose(p[s], q, atol=2e-6)
            np.testing.assert_allclose(np.linalg.norm(p[s] - a.center, axis=1), a.radius,
                                       rtol=1e-6)
            np.testing.assert_allclose(ng[s], nn, atol=2e-6)
            du = np.abs(uv[s] - uvr)
            du[:, 0] = np.minimum(du[:, 0], 1 - du[:, 0])  # phi wraps at 2 pi
            assert du.max() < 2e-5, (target_name, k, du.max())
            # the point lies on the ray at the reported distance
            np.testing.assert_allclose(o[s] + d[s] * np.asarray(out["t"])[s, None], p[s],
                                       atol=2e-5)
        s = geom == 2
        a = desc[2].analytic
        nn, uvr = mitsuba_disk(p[s], a.to_world, flip)
        np.testing.assert_allclose(ng[s], nn, atol=1e-6)
        local = (p[s] @ np.linalg.inv(a.to_world)[:3, :3].T + np.linalg.inv(a.to_world)[:3, 3])
        assert np.abs(local[:, 2]).max() < 1e-5  # on the disk's plane
        du = np.abs(uv[s] - uvr)
        du[:, 1] = np.minimum(du[:, 1], 1 - du[:, 1])
        assert du.max() < 2e-5, (target_name, du.max())
    # the second sphere's normals point inwards (flip_normals); a mirrored disk keeps its side
    assert desc[1].analytic.flipped and not desc[0].analytic.flipped


# ---- rendering --------------------------------------------------------------------------

RHO, LE = 0.5, 2.0


def write_scene(tmp_path: Path, shapes: str, emitters: str = "", *, origin="0,0,4",
                target="0,0,0", fov=30.0, res=16, integrator="path") -> Path:
    path = tmp_path / "scene.xml"
    path.write_text(f"""<scene version="3.0.0">
  <integrator type="{integrator}"/>
  <sensor type="perspective"><float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="0,1,0"/>
    </transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/>
      <integer name="height" value="{res}"/><rfilter type="box"/></film></sensor>
  {shapes}
  {emitters}
</scene>""")
    return path


DIFFUSE = f'<bsdf type="diffuse"><rgb name="reflectance" value="{RHO}"/></bsdf>'
BLACK = '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'  # lights reflect nothing


@pytest.mark.parametrize("shape", [
    f"""<shape type="sphere"><float name="radius" value="1.2"/>
        <transform name="to_world"><rotate x="1" y="2" z="0" angle="70"/></transform>
        {DIFFUSE}</shape>""",
    f"""<shape type="disk"><transform name="to_world"><scale x="2" y="0.5" z="1"/>
        <rotate x="1" angle="-20"/></transform>{DIFFUSE}</shape>""",
])
def test_diffuse_sphere_and_disk_under_a_constant_environment(tmp_path, shape):
    # a convex diffuse surface under a uniform sky reflects RHO * LE everywhere (the disk's
    # front side sees only sky too); the narrow view sees nothing but the shape
    env = f'<emitter type="constant"><rgb name="radiance" value="{LE}"/></emitter>'
    scene = load_scene(write_scene(tmp_path, shape, env, fov=4.0, res=8))
    img = scene.render(spp=256, seed=1)
    assert scene.nonfinite == 0
    assert np.all(np.abs(img - RHO * LE) < 0.1)  # every pixel sees the shape
    np.testing.assert_allclose(img.mean(axis=(0, 1)), RHO * LE, rtol=3e-3)


def test_triangulate_option(tmp_path):
    shapes = f"""<shape type="sphere"><float name="radius" value="0.5"/>
        <boolean name="triangulate" value="true"/>{DIFFUSE}</shape>
      <shape type="disk"><transform name="to_world"><translate z="-1"/></transform>
        {DIFFUSE}</shape>"""
    path = write_scene(tmp_path, shapes, '<emitter type="constant"/>')
    scene = load_scene(path)
    counts = scene.embree.counts
    assert counts[0][1] > 1000 and counts[1] == (0, 0)  # mesh sphere, analytic disk
    everything = load_scene(path, triangulate=True)
    assert all(m > 0 for _, m in everything.embree.counts)
    assert (everything.buffers.G[3::4] & 12).sum() == 0


def sphere_irradiance(le: float, radius: float, dist: float) -> float:
    """Irradiance at a point facing the center of a uniformly emitting sphere."""
    return math.pi * le * (radius / dist) ** 2


def disk_irradiance(le: float, radius: float, h: float) -> float:
    """Irradiance on the axis of a uniformly emitting disk, facing it, at distance h."""
    return math.pi * le * radius ** 2 / (h * h + radius * radius)


@pytest.mark.parametrize("light, expected", [
    (f"""<shape type="sphere"><point name="center" x="0" y="0" z="2"/>
        <float name="radius" value="0.5"/>{BLACK}
        <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>""",
     sphere_irradiance(10.0, 0.5, 2.0)),
    (f"""<shape type="disk"><transform name="to_world"><scale value="0.6"/>
        <rotate x="1" angle="180"/><translate z="1.5"/></transform>{BLACK}
        <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>""",
     disk_irradiance(10.0, 0.6, 1.5)),
])
@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_area_emitting_sphere_and_disk_light_a_plane(tmp_path, light, expected, integrator):
    plane = f"""<shape type="rectangle"><transform name="to_world"><scale value="10"/>
        </transform>{DIFFUSE}</shape>"""
    # the camera looks at the point below the light from the side, past the light (which is
    # black, so that the path tracer sees no light bounced between it and the plane)
    path = write_scene(tmp_path, plane + light, origin="3,0,3", fov=0.5, res=4,
                       integrator=integrator)
    scene = load_scene(path)
    img = scene.render(spp=16384, seed=2)  # per-sample std ~1.6x the mean: ~0.4 % here
    assert scene.nonfinite == 0
    np.testing.assert_allclose(img.mean(axis=(0, 1)), RHO / math.pi * expected, rtol=1.5e-2)


@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_a_white_sphere_light_does_not_light_itself(tmp_path, integrator):
    """A sphere is convex: light it emits never returns to it.  A white diffuse emitting
    sphere alone in the dark therefore shows exactly its radiance.  Emitter sampling from a
    point on the sphere must find nothing there: the cone the sphere subtends degenerates into
    that point (seen from on the surface), where sampling it would give a pdf of about
    1 / 2 pi to a vanishing patch and a bright self-lit halo."""
    white = '<bsdf type="diffuse"><rgb name="reflectance" value="1"/></bsdf>'
    light = f"""<shape type="sphere"><float name="radius" value="0.5"/>{white}
        <emitter type="area"><rgb name="radiance" value="2"/></emitter></shape>"""
    # the narrow view sees the sphere only
    scene = load_scene(write_scene(tmp_path, light, fov=4.0, res=8, integrator=integrator))
    img = scene.render(spp=64, seed=3)
    assert scene.nonfinite == 0
    np.testing.assert_allclose(img, 2.0, rtol=1e-5)


def test_mitsuba_sphere_rules(tmp_path):
    # a non-uniform scale is warned about (as Mitsuba) and the sphere keeps |to_world x|
    shapes = """<shape type="sphere"><transform name="to_world"><scale x="2" y="1" z="1"/>
        </transform></shape>"""
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        scene = load_scene(write_scene(tmp_path, shapes, '<emitter type="constant"/>'))
    assert any("non-uniform scaling" in str(x.message) and "scene.xml:" in str(x.message)
               for x in w)
    assert scene.desc.shapes[0].analytic.radius == pytest.approx(2.0)
    # a mirroring transform flips the normals, as Mitsuba's negative scale
    shapes = """<shape type="sphere"><transform name="to_world"><scale x="-1" y="1" z="1"/>
        </transform></shape>"""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(write_scene(tmp_path, shapes, '<emitter type="constant"/>'))
    assert scene.desc.shapes[0].analytic.flipped
    with pytest.raises(CompileError, match=r"scene\.xml:9:.*radius' must be positive"):
        load_scene(write_scene(tmp_path, '<shape type="sphere"><float name="radius" '
                               'value="-1"/></shape>'))
    with pytest.raises(CompileError, match=r"scene\.xml.*triangulate"):
        load_scene(write_scene(tmp_path, '<shape type="sphere"><string name="triangulate" '
                               'value="maybe"/></shape>'))
