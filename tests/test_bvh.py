"""The BVH written in rdsl (``--accel bvh``) against Embree.

- the binned-SAH builder's tree is valid: each primitive in exactly one leaf, leaves no
  larger than ``leaf_size``, child boxes inside their parent's, escape indices that skip
  exactly the subtree;
- ray by ray, the compiled traversal (stdlib/render/bvh.rdsl) finds Embree's closest hit
  (shape, triangle, t, barycentrics or a disk's local coordinates) and its occlusion, on
  random rays and on rays aimed at triangle edges, over a mesh, spheres and disks; an empty
  scene and a degenerate triangle too;
- the Cornell box and a scene of an OBJ mesh, spheres and disks render the same image with
  ``accel="bvh"`` as with Embree, at the same seed.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.render.bvh import build_bvh, flatten_bvh, scene_bvh

from _scenes import CBOX

embree = pytest.importorskip("rdsl.runtime.embree")
try:
    embree.load_embree()
except Exception as e:  # pragma: no cover - depends on the machine
    pytest.skip(f"Embree is not available: {e}", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]

QUERY_SRC = """
import render.bvh;
struct Q { t: Float, u: Float, v: Float, prim: Int, geom: Int, hit: Bool, blocked: Bool }
fn query(o: Vec3, d: Vec3, tmax: Float, BV: [Float], BI: [Int], P: [Float], G: [Int]) -> Q {
    let ray = Ray { o: o, d: d, tmax: tmax };
    let h = bvh_trace(ray, BV, BI, P, G);
    return Q { t: h.t, u: h.u, v: h.v, prim: h.prim, geom: h.geom, hit: h.valid,
               blocked: bvh_occluded(ray, tmax, BV, BI, P, G) };
}
"""

SCENE = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="50"/>
    <transform name="to_world"><lookat origin="0.3, -3.2, 2.4" target="0, 0, 0.3" up="0, 0, 1"/>
    </transform>
    <sampler type="independent"><integer name="sample_count" value="4"/></sampler>
    <film type="hdrfilm"><integer name="width" value="40"/><integer name="height" value="32"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="obj"><string name="filename" value="grid.obj"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-0.4" y="0.2" z="0.45"/>
    <float name="radius" value="0.35"/>
    <bsdf type="conductor"/></shape>
  <shape type="sphere"><transform name="to_world"><scale value="0.3"/>
    <translate x="0.5" y="-0.3" z="0.5"/></transform>
    <bsdf type="dielectric"/></shape>
  <shape type="disk"><transform name="to_world"><scale x="0.5" y="0.3" z="1"/>
    <rotate x="1" angle="60"/><translate x="0.4" y="0.5" z="0.6"/></transform>
    <bsdf type="diffuse"/></shape>
  <shape type="cube"><transform name="to_world"><scale value="0.15"/>
    <translate x="-0.2" y="-0.6" z="0.3"/></transform><bsdf type="diffuse"/></shape>
  <shape type="disk"><transform name="to_world"><scale value="0.5"/>
    <translate x="0" y="0.5" z="2.2"/><rotate x="1" angle="180"/></transform>
    <emitter type="area"><rgb name="radiance" value="6, 6, 6"/></emitter></shape>
  <emitter type="constant"><rgb name="radiance" value="0.2, 0.2, 0.2"/></emitter>
</scene>
"""


@pytest.fixture(scope="module", params=["host", "scalar"])
def query(request):
    """The traversal as a packet of the host's width (nodes entered when any lane's ray
    meets the box) and ray by ray."""
    return rdsl.jit(QUERY_SRC, target=request.param).query


@pytest.fixture(scope="module")
def mixed_scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bvh_scene")
    shutil.copy(ROOT / "bench" / "scenes" / "compat" / "grid.obj", folder)
    (folder / "mixed.xml").write_text(SCENE)
    return folder / "mixed.xml"


def _check_tree(bvh, lo, hi, leaf_size):
    n = bvh.nodes
    leaves = np.flatnonzero(bvh.count > 0)
    assert bvh.count.max() <= leaf_size
    owned = np.concatenate([bvh.prims[bvh.first[i]:bvh.first[i] + bvh.count[i]] for i in leaves])
    assert np.array_equal(np.sort(owned), np.arange(len(lo)))  # each primitive in one leaf
    for i in leaves:  # a leaf's box holds its primitives
        p = bvh.prims[bvh.first[i]:bvh.first[i] + bvh.count[i]]
        assert np.all(bvh.lo[i] <= lo[p].astype(np.float32))
        assert np.all(bvh.hi[i] >= hi[p].astype(np.float32))
    assert bvh.skip[0] == n
    for i in np.flatnonzero(bvh.count == 0):  # inner: children i + 1 and its escape
        a, b = i + 1, bvh.skip[i + 1]
        assert b < bvh.skip[i] and bvh.skip[b] == bvh.skip[i]
        for c in (a, b):
            assert np.all(bvh.lo[i] <= bvh.lo[c]) and np.all(bvh.hi[c] <= bvh.hi[i])
    for i in leaves:
        assert bvh.skip[i] == i + 1


@pytest.mark.parametrize("leaf_size", [1, 4])
def test_sah_tree_is_valid(leaf_size):
    rng = np.random.default_rng(leaf_size)
    c = np.concatenate([rng.normal(0, 1, (700, 3)), rng.uniform(5, 6, (300, 3)),
                        np.full((40, 3), 2.0)])  # a cluster of coinciding centroids
    size = rng.uniform(0, 0.2, (len(c), 3))
    lo, hi = c - size, c + size
    bvh = build_bvh(lo, hi, leaf_size=leaf_size)
    _check_tree(bvh, lo, hi, leaf_size)
    # the SAH separates the far cluster at the root
    a, b = 1, bvh.skip[1]
    assert min(bvh.hi[a, 0], bvh.hi[b, 0]) < 4.5 < max(bvh.lo[a, 0], bvh.lo[b, 0])


def test_bad_build_options():
    with pytest.raises(ValueError, match="leaf_size"):
        build_bvh(np.zeros((3, 3)), np.ones((3, 3)), leaf_size=0)
    with pytest.raises(CompileError, match="accel"):
        rdsl.load_scene(CBOX, accel="kdtree")


def _rays(bufs, n, seed):
    """Random rays through the scene's box, and rays aimed at points on triangle edges."""
    rng = np.random.default_rng(seed)
    p = bufs.P[:3 * (len(bufs.P) // 3)].reshape(-1, 3)
    lo, hi = p.min(axis=0) - 0.5, p.max(axis=0) + 0.5
    o = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    f = bufs.F.reshape(-1, 3)[rng.integers(0, len(bufs.F) // 3, n // 4)]
    w = rng.random((n // 4, 1))
    edge = p[f[:, 0]] * w + p[f[:, 1]] * (1 - w)  # on edge 0-1 of a random triangle
    d[:n // 4] = edge - o[:n // 4]
    tmax = np.where(rng.random(n) < 0.3, rng.uniform(0.2, 3.0, n), np.inf)
    return o.astype(np.float32), d.astype(np.float32), tmax.astype(np.float32)


def _compare(query, bufs, ref_scene, o, d, tmax):
    got = query(o, d, tmax, bufs.BV, bufs.BI, bufs.P, bufs.G)
    ref = ref_scene.intersect(o, d, tmax)
    hit = np.asarray(got["hit"])
    # a ray through an edge shared by two triangles may hit either, or (rounding) neither:
    # Embree's answer there is one of several; away from edges the answers must agree
    # (float32 barycentrics err by about 1e-5 here, in both),
    flags = bufs.G.reshape(-1, 4)[:, 3]
    grazing = np.zeros(len(o), bool)
    for h, u, v, g in ((ref["hit"], ref["u"], ref["v"], ref["geom_id"]),
                       (hit, np.asarray(got["u"]), np.asarray(got["v"]), np.asarray(got["geom"]))):
        bary = np.minimum(np.minimum(u, v), 1 - u - v)
        grazing |= h & (flags[np.maximum(g, 0)] & 12 == 0) & (bary < 1e-4)  # near an edge
    # and rays almost parallel to the surface they hit, where t is ill-conditioned
    ng = ref["ng"] / np.maximum(np.linalg.norm(ref["ng"], axis=1, keepdims=True), 1e-30)
    grazing |= ref["hit"] & (np.abs(np.sum(ng * d, axis=1)) < 1e-2 * np.linalg.norm(d, axis=1))
    differ = hit != ref["hit"]
    assert not np.any(differ & ~grazing), np.flatnonzero(differ & ~grazing)
    both = hit & ref["hit"] & ~grazing  # a ray through an edge may go on to another hit
    np.testing.assert_allclose(np.asarray(got["t"])[both], ref["t"][both], rtol=2e-5, atol=1e-6)
    for k, k_ref in (("geom", "geom_id"), ("prim", "prim_id")):
        assert np.array_equal(np.asarray(got[k])[both], ref[k_ref][both]), k
    for k in ("u", "v"):
        np.testing.assert_allclose(np.asarray(got[k])[both], ref[k][both], atol=2e-4)
    blocked = np.asarray(got["blocked"])
    assert np.array_equal(blocked[~grazing], ref_scene.occluded(o, d, tmax)[~grazing])
    return hit, ref


def test_hits_match_embree_on_random_and_grazing_rays(query, mixed_scene):
    scene = rdsl.load_scene(mixed_scene, accel="bvh")
    bufs = scene.buffers
    with embree.EmbreeScene(bufs.meshes) as ref_scene:
        o, d, tmax = _rays(bufs, 20000, 1)
        hit, ref = _compare(query, bufs, ref_scene, o, d, tmax)
    # rays aimed at edges may disagree (border edges, rounding); random ones do not
    assert np.array_equal(hit[5000:], ref["hit"][5000:])
    kinds = bufs.G.reshape(-1, 4)[ref["geom_id"][ref["hit"]], 3] & 12
    assert {0, 4, 8} <= set(kinds.tolist())  # mesh, sphere and disk hits were compared
    assert 0.2 < hit.mean() < 0.95


def _buffers(meshes):
    """SceneBuffers-like flat triangles of ``meshes`` [(vertices, faces)]."""
    P = np.concatenate([v.reshape(-1) for v, _ in meshes]).astype(np.float32)
    starts = np.cumsum([0] + [len(v) for v, _ in meshes])
    tstarts = np.cumsum([0] + [len(f) for _, f in meshes])
    F = np.concatenate([f + s for (_, f), s in zip(meshes, starts)]).astype(np.int32)
    G = np.array([[t, 0, -1, 0] for t in tstarts[:-1]], np.int32).reshape(-1)
    bufs = SimpleNamespace(P=P, F=F.reshape(-1), G=G, meshes=meshes)
    bufs.BV, bufs.BI, _ = scene_bvh(bufs)
    return bufs


def test_degenerate_triangle_and_empty_scene(query):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 2, 0], [2, 2, 0], [3, 3, 0]], np.float32)
    f = np.array([[0, 1, 2], [3, 4, 5], [0, 0, 0]], np.uint32)  # a segment, a point
    bufs = _buffers([(v, f)])
    with embree.EmbreeScene(bufs.meshes) as ref_scene:
        rng = np.random.default_rng(3)
        o = np.c_[rng.uniform(-1, 4, (500, 2)), np.full(500, 1.0)].astype(np.float32)
        d = np.tile(np.float32([0, 0, -1]), (500, 1))
        hit, ref = _compare(query, bufs, ref_scene, o, d, np.full(500, np.inf, np.float32))
    assert hit.any() and np.all(np.asarray(ref["prim_id"])[ref["hit"]] == 0)
    empty = build_bvh(np.zeros((0, 3)), np.zeros((0, 3)))
    bv, bi = flatten_bvh(empty, np.zeros(0, int), np.zeros(0, int), np.zeros(3, np.float32),
                         np.zeros(3, np.int32))
    out = query(o[:5], d[:5], np.full(5, np.inf, np.float32), bv, bi,
                np.zeros(3, np.float32), np.zeros(4, np.int32))
    assert not np.any(out["hit"]) and not np.any(out["blocked"])


def _assert_same_image(path, **kw):
    imgs = [rdsl.load_scene(path, accel=a, **kw).render(spp=4, seed=5) for a in ("embree", "bvh")]
    a, b = imgs
    # same seed, same paths: equal to float rounding, except the rare path whose ray meets
    # an edge shared by two triangles and continues from the other one
    diff = np.abs(a - b).max(axis=2)
    assert np.mean(diff > 1e-3 * (1 + a.max(axis=2))) < 0.01
    assert np.abs(a - b).mean() < 1e-3 * a.mean()
    return a


def test_cornell_box_renders_the_same_with_the_bvh():
    img = _assert_same_image(CBOX, res=48)
    assert img.mean() > 0.05


def test_mesh_spheres_disks_render_the_same_with_the_bvh(mixed_scene):
    scene = rdsl.load_scene(mixed_scene, accel="bvh")
    assert scene.bvh is not None and not scene.compile().traces_rays  # no Embree in it
    img = _assert_same_image(mixed_scene)
    assert img.mean() > 0.02


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) on PATH")
def test_c_target_traces_through_the_bvh():
    """The traversal is ordinary stdlib code: the C backend compiles it too (no Embree in
    the C kernel), and its image is the LLVM one with Embree to float rounding.  It is the
    C target's default accel, as on the other targets without Embree."""
    scene = rdsl.load_scene(CBOX, target="c", res=24)
    assert scene.accel == "bvh" and not scene.compile().traces_rays
    got = scene.render(spp=2, seed=3)
    want = rdsl.load_scene(CBOX, res=24).render(spp=2, seed=3)
    np.testing.assert_allclose(got, want, atol=1e-4 * want.max())
