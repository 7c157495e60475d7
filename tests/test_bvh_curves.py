"""Mitsuba's `linearcurve` and `bsplinecurve` traced by the BVH written in rdsl
(``--accel bvh``: stdlib/render/bvh_curves.rdsl) against rdsl's Embree path (Embree 4's
round curves, back faces culled: runtime/embree_curves.py), which tests/test_curves.py
checks against Mitsuba 3 ray by ray.

- ray by ray, on random rays from afar, rays from inside the tubes, rays grazing the tubes,
  rays at the joints between segments and at the ends: the same hit or miss (>= 99.5% of
  the rays of each kind; measured: all 4000 of each kind, of both shapes), the
  same segment, t within 1e-4 relative (but where the ray grazes the surface), u within
  1e-4, and the shading normal and uv geometry.rdsl derives from the hit within 1e-3;
  occlusion queries alike;
- a render with ``accel="bvh"`` is Embree's at the same seed (the same paths);
- the OpenCL target (PoCL) renders a curve scene as the CPU does with the same BVH.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _plugin_scenes import write_scene

import rdsl
from rdsl.compiler.targets import get_target, host_supports
from rdsl.core.scene_spec import SceneSpec

embree = pytest.importorskip("rdsl.runtime.embree")
try:
    embree.load_embree()
except Exception as e:  # pragma: no cover - depends on the machine
    pytest.skip(f"Embree is not available: {e}", allow_module_level=True)


def _curves() -> str:
    """A bent helix of 12 points (joints at every point, radii varying), a straight cone of
    very different end radii in 3 pieces, and short fat segments, some of whose cones lie
    inside their end spheres (|b - a| < |rb - ra|)."""
    s = np.linspace(0, 3.0, 12)
    helix = np.c_[0.6 * np.cos(2 * s), 0.6 * np.sin(2 * s), 0.3 * s - 0.5,
                  0.06 + 0.04 * np.sin(3 * s)]
    w = np.linspace(0, 1, 4)[:, None]
    cone = np.array([-1.2, -0.8, 0.2, 0.3]) * (1 - w) + np.array([0.2, -1.0, -0.2, 0.05]) * w
    fat = np.array([[0.9, 0.8, 0.0, 0.3], [1.0, 0.85, 0.0, 0.1], [1.2, 0.7, 0.1, 0.12],
                    [1.25, 0.5, 0.1, 0.02]])
    return "\n\n".join("\n".join(" ".join(f"{x:.6f}" for x in p) for p in c)
                       for c in (helix, cone, fat)) + "\n"


PROBE = """
import render.bvh;
struct Out { hit: Bool, t: Float, u: Float, prim: Int, geom: Int, blocked: Bool, n: Vec3,
             uv: Vec2 }
fn out(ray: Ray, h: Hit, blocked: Bool, P: [Float], N: [Float], UV: [Float], F: [Int],
       G: [Int]) -> Out {
    var n = Vec3(0.0, 0.0, 0.0);
    var uv = Vec2(0.0, 0.0);
    if h.valid {
        let it = interaction(ray, h, P, N, UV, F, G);
        n = it.frame.n;
        uv = it.si.uv;
    }
    return Out { hit: h.valid, t: h.t, u: h.u, prim: h.prim, geom: h.geom, blocked: blocked,
                 n: n, uv: uv };
}
fn with_embree(o: Vec3, d: Vec3, tmax: Float, P: [Float], N: [Float], UV: [Float], F: [Int],
               G: [Int]) -> Out {
    let ray = Ray { o: o, d: d, tmax: tmax };
    return out(ray, trace(ray), occluded(ray), P, N, UV, F, G);
}
fn with_bvh(o: Vec3, d: Vec3, tmax: Float, BV: [Float], BI: [Int], P: [Float], N: [Float],
            UV: [Float], F: [Int], G: [Int]) -> Out {
    let ray = Ray { o: o, d: d, tmax: tmax };
    return out(ray, bvh_trace(ray, BV, BI, P, G), bvh_occluded(ray, tmax, BV, BI, P, G), P, N,
               UV, F, G);
}
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bvh_curves")
    (folder / "curves.txt").write_text(_curves())
    return folder


def _axis_points(kind: str, points: np.ndarray, segments: np.ndarray, rng, n: int,
                 ends: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random points c(u) on the segments' axes (with ``ends``, their ends): the points,
    the axis directions there, r(u)."""
    k = segments[rng.integers(len(segments), size=n)]
    u = (rng.integers(2, size=n) if ends else rng.random(n))[:, None]
    if kind == "linearcurve":
        a, b = points[k], points[k + 1]
        c, dc = a * (1 - u) + b * u, b - a
    else:  # the uniform cubic B-spline basis and its derivative
        q = [points[k + i] for i in range(4)]
        w = [(1 - u) ** 3, 3 * u**3 - 6 * u**2 + 4, -3 * u**3 + 3 * u**2 + 3 * u + 1, u**3]
        dw = [-3 * (1 - u) ** 2, 9 * u**2 - 12 * u, -9 * u**2 + 6 * u + 3, 3 * u**2]
        c = sum(wi * qi for wi, qi in zip(w, q)) / 6
        dc = sum(wi * qi for wi, qi in zip(dw, q))
    return c[:, :3], dc[:, :3], c[:, 3]


def _perpendicular(axis: np.ndarray, rng) -> np.ndarray:
    v = np.cross(axis, rng.normal(size=axis.shape))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _rays(kind: str, points: np.ndarray, segments: np.ndarray, n: int, seed: int
          ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Rays of each kind (origins, unit directions)."""
    rng = np.random.default_rng(seed)
    centre = points[:, :3].mean(axis=0)
    far = rng.normal(size=(n, 3)) * 3 + centre
    rays = {"afar": (far, rng.normal(size=(n, 3)) * 0.6 + centre - far)}
    c, _, _ = _axis_points(kind, points, segments, rng, n)  # from inside the tubes
    rays["inside"] = (c, rng.normal(size=(n, 3)))
    # grazing: passing at 0.97 to 1.03 radii from the axis, across it
    c, axis, r = _axis_points(kind, points, segments, rng, n)
    side = _perpendicular(axis, rng)
    across = np.cross(axis, side)
    o = c + side * (r * rng.uniform(0.97, 1.03, n))[:, None] - across * 2
    rays["grazing"] = (o, across + rng.normal(size=(n, 3)) * 0.02)
    # at the joints and ends: aimed at points around the segments' ends
    c, _, r = _axis_points(kind, points, segments, rng, n, ends=True)
    on = c + rng.normal(size=(n, 3)) * r[:, None] * 0.7
    o = on + rng.normal(size=(n, 3)) * 2
    rays["joints"] = (o, on - o)
    return {k: (o.astype(np.float32), (d / np.linalg.norm(d, axis=1, keepdims=True))
                .astype(np.float32)) for k, (o, d) in rays.items()}


def _check_hits(what: str, got: dict, ref: dict, d: np.ndarray, least: float) -> int:
    """The BVH's answers ``got`` are Embree's ``ref``; at least ``least`` of the rays hit
    (rays from inside a tube pass out of it and hit only other segments): how many hits
    were compared."""
    agree = got["hit"] == ref["hit"]
    assert agree.mean() >= 0.995, (what, agree.mean())
    assert (got["blocked"] == ref["blocked"]).mean() >= 0.995, what
    assert least < ref["hit"].mean() < 0.95, (what, ref["hit"].mean())
    # t is ill-conditioned where a ray grazes the surface
    both = got["hit"] & ref["hit"] & (np.abs(np.sum(ref["n"] * d, axis=1)) > 1e-2)
    assert both.sum() > 0.5 * ref["hit"].sum(), what
    np.testing.assert_allclose(got["t"][both], ref["t"][both], rtol=1e-4, atol=1e-5,
                               err_msg=what)
    assert np.array_equal(got["prim"][both], ref["prim"][both]), what
    for k, tol in (("u", 1e-4), ("n", 1e-3)):
        np.testing.assert_allclose(got[k][both], ref[k][both], atol=tol, err_msg=what)
    du = np.abs(got["uv"][both] - ref["uv"][both])
    assert np.all(np.minimum(du[:, 0], 1 - du[:, 0]) < 1e-3), what  # u wraps around
    assert np.all(du[:, 1] < 1e-4), what
    return int(both.sum())


@pytest.mark.parametrize("kind", ["linearcurve", "bsplinecurve"])
def test_hits_match_embree(folder, kind):
    """Ray by ray, the rdsl BVH finds rdsl's Embree hit (segment, t, u) on every kind of ray,
    and the shading normal and uv derived from it are Embree's."""
    path = folder / f"{kind}.xml"
    path.write_text(f'<scene version="3.0.0"><shape type="{kind}"><string name="filename" '
                    'value="curves.txt"/></shape></scene>')
    scene = rdsl.load_scene(path, accel="bvh")
    b = scene.buffers
    mod = rdsl.jit(PROBE, scene=SceneSpec())
    curves = scene.desc.shapes[0].curves
    checked = 0
    with embree.EmbreeScene(b.meshes) as ref_scene:
        mod.bind_scene(ref_scene)
        for which, (o, d) in _rays(kind, curves.points, curves.segments, 4000, 1).items():
            tmax = np.full(len(o), np.inf, np.float32)
            tmax[::5] = np.random.default_rng(2).uniform(0.5, 3.0, len(tmax[::5]))
            ref = {k: np.asarray(v) for k, v in
                   mod.with_embree(o, d, tmax, b.P, b.N, b.UV, b.F, b.G).items()}
            got = {k: np.asarray(v) for k, v in
                   mod.with_bvh(o, d, tmax, b.BV, b.BI, b.P, b.N, b.UV, b.F, b.G).items()}
            checked += _check_hits(f"{kind}, {which} rays", got, ref, d,
                                   0.01 if which == "inside" else 0.05)
    assert checked > 4000


def _scene(folder: Path, name: str = "scene.xml") -> Path:
    return write_scene(folder, '<shape type="linearcurve"><string name="filename" '
                       'value="curves.txt"/><bsdf type="roughconductor"/></shape>'
                       '<shape type="bsplinecurve"><string name="filename" value="curves.txt"/>'
                       '<transform name="to_world"><rotate z="1" angle="90"/>'
                       '<translate z="-0.5"/></transform></shape>', name=name)


def test_render_matches_embree(folder):
    """The same seed gives the same paths: Embree's image to float rounding, but for the
    rare path that rounding sends the other way at a grazing hit."""
    path = _scene(folder)
    a, b = (rdsl.load_scene(path, accel=accel).render(spp=4, seed=7)
            for accel in ("embree", "bvh"))
    assert a.mean() > 0.05
    diff = np.abs(a - b).max(axis=2)
    assert np.mean(diff > 1e-3 * (1 + a.max(axis=2))) < 0.01
    assert np.abs(a - b).mean() < 2e-3 * a.mean()


def test_opencl_renders_curves_as_the_cpu(folder):
    """PoCL's OpenCL kernel traces the curves through the same rdsl BVH: the LLVM target's
    image with the BVH bit for bit (the same IR, rounded alike), and Embree's within float
    rounding."""
    from rdsl.runtime.opencl import OpenCLUnavailable, opencl_context

    try:
        opencl_context()
    except OpenCLUnavailable as e:
        pytest.skip(str(e))
    path = _scene(folder, "cl.xml")
    host = "avx2" if host_supports(get_target("avx2")) else "scalar"
    imgs = {target: rdsl.load_scene(path, target=target, accel="bvh").render(spp=2, seed=3)
            for target in ("opencl", host)}
    ref = rdsl.load_scene(path, target=host).render(spp=2, seed=3)
    assert ref.mean() > 0.05
    assert np.array_equal(imgs["opencl"], imgs[host])
    diff = np.abs(imgs["opencl"] - ref).max(axis=2)
    assert np.mean(diff > 1e-3 * (1 + ref.max(axis=2))) < 0.02

