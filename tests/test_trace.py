"""Ray queries from compiled rdsl kernels (`trace`, `occluded`) call Embree directly; on
random rays against a triangle soup and a cube they agree with a brute-force float64
Moller-Trumbore intersector on every target."""

from __future__ import annotations

import numpy as np
import pytest

import rdsl
from rdsl.compiler.targets import get_target, host_supports

embree = pytest.importorskip("rdsl.runtime.embree")
try:
    embree.load_embree()
except Exception as e:  # pragma: no cover - depends on the machine
    pytest.skip(f"Embree is not available: {e}", allow_module_level=True)

SRC = """
fn hit(o: Vec3, d: Vec3, tmax: Float) -> Vec4 {
    let h = trace(Ray { o: o, d: d, tmax: tmax });
    if !h.valid { return Vec4(-1.0); }
    return Vec4(h.t, Float(h.prim), Float(h.geom), h.u + h.v);
}
fn blocked(o: Vec3, d: Vec3, tmax: Float) -> Bool {
    return occluded(Ray { o: o, d: d, tmax: tmax });
}
"""
TARGETS = [t for t in ("scalar", "sse4", "avx2", "avx512") if host_supports(get_target(t))]


def brute_force(tris: np.ndarray, o: np.ndarray, d: np.ndarray, tmax: np.ndarray):
    """Closest hit per ray (t, triangle) in float64, inf/-1 on a miss."""
    v0, v1, v2 = (tris[:, k].astype(np.float64) for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    o = o.astype(np.float64)[:, None]
    d = d.astype(np.float64)[:, None]
    p = np.cross(d, e2)
    det = np.sum(e1 * p, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o - v0
        u = np.sum(s * p, axis=-1) * inv
        q = np.cross(s, e1)
        v = np.sum(d * q, axis=-1) * inv
        t = np.sum(e2 * q, axis=-1) * inv
    ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) \
        & (t <= tmax[:, None])
    t = np.where(ok, t, np.inf)
    best = np.argmin(t, axis=1)
    tbest = t[np.arange(len(t)), best]
    return tbest, np.where(np.isfinite(tbest), best, -1), np.sort(t, axis=1)


def scene_cases():
    rng = np.random.default_rng(3)
    soup = rng.uniform(-1, 1, (60, 3, 3)).astype(np.float32)
    cube_v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                      np.float32) * 0.7
    cube_f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                      np.uint32)
    return {"soup": (soup.reshape(-1, 3), np.arange(180, dtype=np.uint32).reshape(-1, 3)),
            "cube": (cube_v, cube_f)}


@pytest.fixture(scope="module")
def modules():
    return {t: rdsl.jit(SRC, target=t) for t in TARGETS}


@pytest.mark.parametrize("case", ["soup", "cube"])
def test_trace_matches_brute_force(case, modules):
    v, f = scene_cases()[case]
    scene = embree.EmbreeScene([(v, f)])
    rng = np.random.default_rng(11)
    n = 1001  # not a multiple of any width: the tails are masked
    o = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    d = rng.standard_normal((n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tmax = np.where(rng.random(n) < 0.25, rng.uniform(0.1, 2, n), 100).astype(np.float32)
    t_ref, prim_ref, t_sorted = brute_force(v[f], o, d, tmax)
    # rays whose two nearest hits are nearly tied may pick either triangle
    with np.errstate(invalid="ignore"):  # inf - inf on misses
        clear = ~(np.abs(t_sorted[:, 0] - t_sorted[:, 1]) < 1e-4)
    for target, mod in modules.items():
        mod.bind_scene(scene)
        out = mod.hit(o, d, tmax)
        hit = out[:, 0] >= 0
        assert np.array_equal(hit[clear], np.isfinite(t_ref)[clear]), target
        both = hit & clear
        np.testing.assert_allclose(out[both, 0], t_ref[both], rtol=1e-4, err_msg=target)
        assert np.array_equal(out[both, 1].astype(int), prim_ref[both]), target
        assert np.all(out[both, 2] == 0) and np.all(out[both, 3] <= 1 + 1e-5)
        blocked = mod.blocked(o, d, tmax)
        assert np.array_equal(blocked[clear], np.isfinite(t_ref)[clear]), target


def test_mask_and_unbound_scene(modules):
    v, f = scene_cases()["cube"]
    scene = embree.EmbreeScene([(v, f)])
    mod = modules[TARGETS[-1]]
    mod.bind_scene(scene)
    o = np.zeros((20, 3), np.float32)
    d = np.tile(np.float32([0, 0, 1]), (20, 1))
    mask = np.arange(20) % 3 == 0
    out = mod.hit(o, d, np.full(20, 10, np.float32), mask=mask)
    np.testing.assert_allclose(out[mask, 0], 0.7, rtol=1e-6)
    assert np.all(out[~mask] == 0)  # inactive lanes write zeros
    with pytest.raises(ValueError, match="traces no rays"):
        rdsl.jit("fn f(x: Float) -> Float { return x; }", target="scalar").bind_scene(scene)
