"""Sampling code of the stdlib: warps, PCG32, microfacet distributions and Fresnel terms.

Each rdsl source compiles once per module (scalar target). Densities are checked three ways:
mapped points lie in the domain, the pdf integrates to 1 (midpoint quadrature), and the pdf
matches a histogram of samples (Pearson's chi-square over bins of equal parameter size, with
the expected counts integrated from the pdf).
"""

from __future__ import annotations

import numpy as np
import pytest
import rdsl

f32 = np.float32
RNG = np.random.default_rng(7)

WARP_SRC = """
import warp;
fn w_disk(u: Vec2) -> Vec2 { return square_to_uniform_disk(u); }
fn w_disk_concentric(u: Vec2) -> Vec2 { return square_to_uniform_disk_concentric(u); }
fn w_cosine(u: Vec2) -> Vec3 { return square_to_cosine_hemisphere(u); }
fn w_sphere(u: Vec2) -> Vec3 { return square_to_uniform_sphere(u); }
fn w_hemisphere(u: Vec2) -> Vec3 { return square_to_uniform_hemisphere(u); }
fn w_triangle(u: Vec2) -> Vec2 { return square_to_uniform_triangle(u); }
fn p_cosine(v: Vec3) -> Float { return square_to_cosine_hemisphere_pdf(v); }
fn p_sphere(v: Vec3) -> Float { return square_to_uniform_sphere_pdf(v); }
fn p_hemisphere(v: Vec3) -> Float { return square_to_uniform_hemisphere_pdf(v); }
fn w_cone(u: Vec2) -> Vec3 { return square_to_uniform_cone(u, 0.8); }
fn p_cone(v: Vec3) -> Float { return square_to_uniform_cone_pdf(v, 0.8); }
fn frame_roundtrip(n: Vec3, v: Vec3) -> Vec3 { return to_world(coordinate_system(n), v); }
fn frame_check(n: Vec3) -> Vec4 {
    let f = coordinate_system(n);
    return Vec4(dot(f.s, f.t), dot(f.s, f.n), dot(f.t, f.n), dot(cross(f.s, f.t), f.n));
}
fn frame_phi(v: Vec3) -> Vec4 {
    let (s, c) = sincos_phi(v);
    return Vec4(s, c, sin2_phi(v) + cos2_phi(v), tan2_theta(v));
}
"""

PCG_SRC = """
import pcg32;
fn seeded(initstate: UInt64, initseq: UInt64, n: Int, out_u: [UInt], out_f: [Float]) {
    var r = pcg32_seed(initstate, initseq);
    for i in 0..n {
        let (r1, v) = pcg32_next_uint(r);
        r = r1;
        out_u[i] = v;
    }
    for i in 0..n {
        let (r1, x) = pcg32_next_float(r);
        r = r1;
        out_f[i] = x;
    }
}
fn default_seq(n: Int, out_u: [UInt]) {
    var r = pcg32_default();
    for i in 0..n {
        let (r1, v) = pcg32_next_uint(r);
        r = r1;
        out_u[i] = v;
    }
}
fn nth(initstate: UInt64, initseq: UInt64, i: UInt64) -> UInt {
    let (r, v) = pcg32_next_uint(pcg32_advance(pcg32_seed(initstate, initseq), i));
    return v;
}
fn bounded(seed: UInt64, bound: UInt, n: Int, out_u: [UInt]) {
    var r = pcg32_seed(seed, 1ul);
    for i in 0..n {
        let (r1, v) = pcg32_next_uint_bounded(r, bound);
        r = r1;
        out_u[i] = v;
    }
}
fn lane_float(seed: UInt64) -> Float {
    let (r, x) = pcg32_next_float(pcg32_seed(seed, 1ul));
    return x;
}
"""

MF_SRC = """
import microfacet;
fn d_ggx(m: Vec3, ax: Float, ay: Float) -> Float { return ggx_d(m, ax, ay); }
fn d_beckmann(m: Vec3, ax: Float, ay: Float) -> Float { return beckmann_d(m, ax, ay); }
fn g1_ggx(v: Vec3, m: Vec3, ax: Float, ay: Float) -> Float { return smith_g1_ggx(v, m, ax, ay); }
fn g1_beckmann(v: Vec3, m: Vec3, ax: Float, ay: Float) -> Float {
    return smith_g1_beckmann(v, m, ax, ay);
}
fn g_ggx(wi: Vec3, wo: Vec3, m: Vec3, a: Float) -> Float { return smith_g_ggx(wi, wo, m, a); }
fn s_ggx(wi: Vec3, ax: Float, ay: Float, u: Vec2) -> Vec3 {
    return sample_visible_ggx(wi, ax, ay, u);
}
fn s_beckmann(wi: Vec3, ax: Float, ay: Float, u: Vec2) -> Vec3 {
    return sample_visible_beckmann(wi, ax, ay, u);
}
fn pv_ggx(wi: Vec3, m: Vec3, ax: Float, ay: Float) -> Float {
    return pdf_visible_ggx(wi, m, ax, ay);
}
fn pv_beckmann(wi: Vec3, m: Vec3, ax: Float, ay: Float) -> Float {
    return pdf_visible_beckmann(wi, m, ax, ay);
}
fn iso_consistent(wi: Vec3, m: Vec3, a: Float, u: Vec2) -> Vec4 {
    let s = sample_visible_ggx(wi, a, u);
    let t = sample_visible_ggx(wi, a, a, u);
    return Vec4(ggx_d(m, a) - ggx_d(m, a, a),
                pdf_visible_ggx(wi, m, a) - pdf_visible_ggx(wi, m, a, a),
                length(s - t), beckmann_d(m, a) - beckmann_d(m, a, a));
}
"""

FRESNEL_SRC = """
import fresnel;
fn fd(cos_theta_i: Float, eta: Float) -> Vec4 {
    let (f, ct, eta_it, eta_ti) = fresnel_dielectric(cos_theta_i, eta);
    return Vec4(f, ct, eta_it, eta_ti);
}
fn fc(cos_theta_i: Float, eta: Float, k: Float) -> Float {
    return fresnel_conductor(cos_theta_i, eta, k);
}
fn fc_rgb(cos_theta_i: Float, eta: Vec3, k: Vec3) -> Spectrum {
    return fresnel_conductor(cos_theta_i, Spectrum(eta.x, eta.y, eta.z), Spectrum(k.x, k.y, k.z));
}
"""


@pytest.fixture(scope="module")
def warp():
    return rdsl.jit(WARP_SRC, target="scalar")


@pytest.fixture(scope="module")
def pcg():
    return rdsl.jit(PCG_SRC, target="scalar")


@pytest.fixture(scope="module")
def mf():
    return rdsl.jit(MF_SRC, target="scalar")


@pytest.fixture(scope="module")
def fres():
    return rdsl.jit(FRESNEL_SRC, target="scalar")


# ---------------------------------------------------------------------------- helpers

def uniform2(n: int) -> np.ndarray:
    return RNG.random((n, 2)).astype(np.float32)


def sph(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], -1).astype(np.float32)


def integrate_sphere(pdf, theta_max: float = np.pi, n_theta: int = 1024, n_phi: int = 256,
                     theta_edges: np.ndarray | None = None) -> float:
    """Midpoint rule of pdf(dirs) over theta in [0, theta_max] (or given edges) and phi."""
    if theta_edges is None:
        theta_edges = np.linspace(0, theta_max, n_theta + 1)
    th = 0.5 * (theta_edges[1:] + theta_edges[:-1])
    dth = np.diff(theta_edges)
    ph = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    vals = np.asarray(pdf(sph(T.ravel(), P.ravel())), np.float64).reshape(T.shape)
    assert np.all(np.isfinite(vals))
    return float(np.sum(vals * np.sin(T) * dth[:, None]) * (2 * np.pi / n_phi))


def theta_edges_for(alpha: float, theta_max: float = np.pi / 2, k: int = 12) -> np.ndarray:
    """Bin edges in theta with equal steps in atan(tan(theta) / alpha): follows a peak of
    width ~alpha at the pole."""
    s = np.linspace(0, np.arctan(np.tan(min(theta_max, 1.5707)) / alpha), k + 1)
    e = np.arctan(alpha * np.tan(s))
    e[-1] = theta_max
    return e


def chi2_test(dirs: np.ndarray, pdf, theta_edges: np.ndarray, n_phi: int = 12,
              sub: int = 24, min_expected: float = 20.0) -> None:
    """Pearson's chi-square of the sample directions against pdf over (theta, phi) bins."""
    n = len(dirs)
    theta = np.arccos(np.clip(dirs[:, 2].astype(np.float64), -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0]) % (2 * np.pi)
    phi_edges = np.linspace(0, 2 * np.pi, n_phi + 1)
    observed, _, _ = np.histogram2d(theta, phi, bins=[theta_edges, phi_edges])
    # expected counts: midpoint rule with sub x sub points inside each bin
    k = len(theta_edges) - 1
    fr = (np.arange(sub) + 0.5) / sub
    th = (theta_edges[:-1, None] + np.diff(theta_edges)[:, None] * fr[None, :])   # (k, sub)
    ph = (phi_edges[:-1, None] + np.diff(phi_edges)[:, None] * fr[None, :])       # (n_phi, sub)
    T = np.broadcast_to(th[:, None, :, None], (k, n_phi, sub, sub))
    P = np.broadcast_to(ph[None, :, None, :], (k, n_phi, sub, sub))
    vals = np.asarray(pdf(sph(T.ravel(), P.ravel())), np.float64).reshape(T.shape)
    area = np.diff(theta_edges)[:, None] * np.diff(phi_edges)[None, :] / (sub * sub)
    expected = n * np.sum(vals * np.sin(T), axis=(2, 3)) * area
    # pool the sparse bins into one
    sparse = expected < min_expected
    obs = np.append(observed[~sparse], observed[sparse].sum())
    exp = np.append(expected[~sparse], expected[sparse].sum())
    keep = exp > 0
    assert np.all(obs[~keep] == 0), "samples where the pdf is zero"
    stat = float(np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep]))
    dof = int(keep.sum()) - 1
    # the chi-square distribution is ~ normal(dof, 2 dof) here; 6 sigma keeps the test stable
    limit = dof + 6 * np.sqrt(2 * dof)
    assert stat < limit, f"chi2 = {stat:.1f} > {limit:.1f} (dof {dof})"


# ---------------------------------------------------------------------------- warps

def test_disks(warp):
    u = uniform2(100_000)
    for name in ("w_disk", "w_disk_concentric"):
        p = warp[name](u)
        r2 = np.sum(p.astype(np.float64) ** 2, axis=1)
        assert np.all(r2 <= 1 + 1e-6), name
        # uniform on the disk: r^2 and phi are uniform; chi-square on a 10 x 16 grid
        phi = np.arctan2(p[:, 1], p[:, 0]) % (2 * np.pi)
        h, _, _ = np.histogram2d(r2, phi, bins=[np.linspace(0, 1, 11),
                                                np.linspace(0, 2 * np.pi, 17)])
        e = len(u) / h.size
        stat = np.sum((h - e) ** 2 / e)
        assert stat < h.size - 1 + 6 * np.sqrt(2 * (h.size - 1)), name
    assert np.all(warp["w_disk_concentric"](np.array([[0.5, 0.5]], f32)) == 0)


@pytest.mark.parametrize("name,pdf_name,theta_max", [
    ("w_cosine", "p_cosine", np.pi / 2),
    ("w_sphere", "p_sphere", np.pi),
    ("w_hemisphere", "p_hemisphere", np.pi / 2),
    ("w_cone", "p_cone", np.arccos(0.8)),
])
def test_direction_warps(warp, name, pdf_name, theta_max):
    corners = [[0, 0], [1, 1], [0.5, 0.5], [0, 1], [1, 0]]
    u = np.concatenate([uniform2(100_000), corners]).astype(f32)
    v = warp[name](u)
    assert np.all(np.isfinite(v))
    np.testing.assert_allclose(np.linalg.norm(v.astype(np.float64), axis=1), 1.0, atol=2e-6)
    if theta_max < np.pi:
        assert np.all(v[:, 2] >= 0)
    pdf = warp[pdf_name]
    assert integrate_sphere(pdf, theta_max) == pytest.approx(1.0, abs=2e-4)
    chi2_test(v[:100_000], pdf, np.linspace(0, theta_max, 13))


def test_triangle(warp):
    p = warp["w_triangle"](uniform2(100_000)).astype(np.float64)
    assert np.all(p >= 0) and np.all(p.sum(1) <= 1 + 1e-6)
    # moments of the uniform triangle: E[x] = 1/3, E[x^2] = 1/6, E[xy] = 1/12
    assert p.mean(0) == pytest.approx([1 / 3, 1 / 3], abs=3e-3)
    assert np.mean(p[:, 0] ** 2) == pytest.approx(1 / 6, abs=3e-3)
    assert np.mean(p[:, 0] * p[:, 1]) == pytest.approx(1 / 12, abs=3e-3)


def test_frame(warp):
    n = RNG.normal(size=(20_000, 3))
    n = np.concatenate([n, [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 0, -1e-9], [1e-7, 0, -1]]])
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(f32)
    c = warp["frame_check"](n)
    assert np.all(np.isfinite(c))
    np.testing.assert_allclose(c[:, :3], 0.0, atol=2e-6)
    np.testing.assert_allclose(c[:, 3], 1.0, atol=2e-6)
    v = RNG.normal(size=(len(n), 3)).astype(f32)
    w = warp["frame_roundtrip"](n, np.array([[0, 0, 1]] * len(n), f32))
    np.testing.assert_allclose(w, n, atol=2e-6)
    assert np.all(np.isfinite(warp["frame_roundtrip"](n, v)))
    d = sph(RNG.uniform(0.01, np.pi - 0.01, 1000), RNG.uniform(-np.pi, np.pi, 1000))
    d = np.concatenate([d, [[0, 0, 1], [0, 0, -1]]]).astype(f32)
    out = warp["frame_phi"](d)
    phi = np.arctan2(d[:, 1], d[:, 0])
    np.testing.assert_allclose(out[:-2, 0], np.sin(phi[:-2]), atol=1e-5)
    np.testing.assert_allclose(out[:-2, 1], np.cos(phi[:-2]), atol=1e-5)
    np.testing.assert_allclose(out[:, 2], 1.0, atol=1e-5)
    tan2 = (1 - d[:, 2].astype(np.float64) ** 2) / d[:, 2].astype(np.float64) ** 2
    np.testing.assert_allclose(out[:-2, 3], tan2[:-2], rtol=2e-4)
    np.testing.assert_array_equal(out[-2:, :2], [[0, 1], [0, 1]])


# ---------------------------------------------------------------------------- PCG32

MASK64 = (1 << 64) - 1
MULT = 0x5851F42D4C957F2D


def pcg_reference(state: int, inc: int, n: int) -> tuple[list[int], int, int]:
    """O'Neill's pcg32_random_r with explicit 64-bit wrapping."""
    out = []
    for _ in range(n):
        old = state
        state = (old * MULT + inc) & MASK64
        xorshifted = (((old >> 18) ^ old) >> 27) & 0xFFFFFFFF
        rot = old >> 59
        out.append(((xorshifted >> rot) | (xorshifted << ((-rot) & 31))) & 0xFFFFFFFF)
    return out, state, inc


def pcg_seed_reference(initstate: int, initseq: int) -> tuple[int, int]:
    inc = ((initseq << 1) | 1) & MASK64
    _, state, _ = pcg_reference(0, inc, 1)
    _, state, _ = pcg_reference((state + initstate) & MASK64, inc, 1)
    return state, inc


def test_pcg32_default_sequence(pcg):
    out = np.zeros(1000, np.uint32)
    pcg["default_seq"](np.array([1000], np.int32), out)
    ref, _, _ = pcg_reference(0x853C49E6748FEA9B, 0xDA3E39CB94B95BDB, 1000)
    np.testing.assert_array_equal(out, np.array(ref, np.uint32))


@pytest.mark.parametrize("initstate,initseq", [(42, 54), (0, 0), (2**64 - 1, 2**63 + 5)])
def test_pcg32_seeded_sequence(pcg, initstate, initseq):
    out_u = np.zeros(1000, np.uint32)
    out_f = np.zeros(1000, np.float32)
    pcg["seeded"](np.array([initstate], np.uint64), np.array([initseq], np.uint64),
                  np.array([1000], np.int32), out_u, out_f)
    state, inc = pcg_seed_reference(initstate, initseq)
    ref, _, _ = pcg_reference(state, inc, 2000)
    np.testing.assert_array_equal(out_u, np.array(ref[:1000], np.uint32))
    # floats: the top 23 bits as the mantissa of [1, 2), minus 1 (exact in float32)
    ref_f = (np.array(ref[1000:], np.uint64) >> 9).astype(np.float64) / 2.0**23
    np.testing.assert_array_equal(out_f, ref_f.astype(np.float32))
    assert np.all((out_f >= 0) & (out_f < 1))
    if (initstate, initseq) == (42, 54):
        # the first outputs of O'Neill's pcg32-demo
        assert [hex(v) for v in out_u[:6]] == ["0xa15c02b7", "0x7b47f409", "0xba1d3330",
                                                "0x83d2f293", "0xbfa4784b", "0xcbed606e"]


def test_pcg32_advance(pcg):
    i = np.array([0, 1, 2, 17, 999], np.uint64)
    got = pcg["nth"](np.full(5, 42, np.uint64), np.full(5, 54, np.uint64), i)
    state, inc = pcg_seed_reference(42, 54)
    ref, _, _ = pcg_reference(state, inc, 1000)
    np.testing.assert_array_equal(got, np.array([ref[int(k)] for k in i], np.uint32))


def test_pcg32_bounded(pcg):
    """Mitsuba's next_uint32(bound): rejection below (2^32 - bound) % bound, then modulo."""
    for bound in (1, 7, 1000, 2**31 + 3):
        out = np.zeros(2000, np.uint32)
        pcg["bounded"](np.array([9], np.uint64), np.array([bound], np.uint32),
                       np.array([2000], np.int32), out)
        state, inc = pcg_seed_reference(9, 1)
        ref, threshold = [], (2**32 - bound) % bound
        while len(ref) < 2000:
            (v,), state, inc = pcg_reference(state, inc, 1)
            if v >= threshold:
                ref.append(v % bound)
        np.testing.assert_array_equal(out, np.array(ref, np.uint32))
        assert np.all(out < bound)


def test_pcg32_host_matches_scalar(pcg):
    """Vectorized: a different loop trip count per lane in pcg32_advance."""
    host = rdsl.jit(PCG_SRC, target="host")
    i = RNG.integers(0, 2**40, 1001, dtype=np.uint64)
    s, q = np.full(1001, 42, np.uint64), RNG.integers(0, 2**63, 1001, dtype=np.uint64)
    np.testing.assert_array_equal(host["nth"](s, q, i), pcg["nth"](s, q, i))
    seeds = np.arange(1001, dtype=np.uint64)
    np.testing.assert_array_equal(host["lane_float"](seeds), pcg["lane_float"](seeds))


def test_pcg32_float_range(pcg):
    x = pcg["lane_float"](np.arange(100_000, dtype=np.uint64))
    assert np.all((x >= 0) & (x < 1))
    assert x.mean() == pytest.approx(0.5, abs=5e-3)
    h, _ = np.histogram(x, bins=20, range=(0, 1))
    assert np.sum((h - 5000.0) ** 2 / 5000.0) < 19 + 6 * np.sqrt(38)


# ---------------------------------------------------------------------------- microfacets

ALPHAS = [(0.1, 0.1), (0.5, 0.5), (1.0, 1.0), (0.15, 0.6)]
WI_THETAS = [0.0, 0.6, 1.2, 1.5]


def _wi(theta: float, phi: float = 0.7) -> np.ndarray:
    return sph(np.array([theta]), np.array([phi]))[0]


def _tile(v: np.ndarray, n: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(v, (n, len(v))), dtype=np.float32)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("ax,ay", ALPHAS)
def test_d_normalized(mf, dist, ax, ay):
    d = mf[f"d_{dist}"]
    edges = np.concatenate([theta_edges_for(min(ax, ay), k=400)])
    total = integrate_sphere(lambda m: d(m, np.full(len(m), ax, f32), np.full(len(m), ay, f32))
                             * m[:, 2], theta_edges=edges, n_phi=128)
    assert total == pytest.approx(1.0, abs=3e-3)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("ax,ay", ALPHAS)
@pytest.mark.parametrize("theta_i", WI_THETAS)
def test_visible_pdf_integrates_to_one(mf, dist, ax, ay, theta_i):
    wi = _wi(theta_i)
    pv = mf[f"pv_{dist}"]

    def pdf(m):
        n = len(m)
        return pv(_tile(wi, n), m, np.full(n, ax, f32), np.full(n, ay, f32))

    total = integrate_sphere(pdf, theta_edges=theta_edges_for(min(ax, ay), k=400), n_phi=128)
    # Beckmann's rational G1 is within 0.35% of the exact one
    assert total == pytest.approx(1.0, abs=3e-3 if dist == "ggx" else 6e-3)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
@pytest.mark.parametrize("ax,ay", [(0.1, 0.1), (0.5, 0.5), (0.15, 0.6)])
@pytest.mark.parametrize("theta_i", [0.0, 0.8, 1.45])
def test_visible_sampling_matches_pdf(mf, dist, ax, ay, theta_i):
    n = 100_000
    wi = _wi(theta_i)
    A, B = np.full(n, ax, f32), np.full(n, ay, f32)
    m = mf[f"s_{dist}"](_tile(wi, n), A, B, uniform2(n))
    assert np.all(np.isfinite(m))
    np.testing.assert_allclose(np.linalg.norm(m.astype(np.float64), axis=1), 1, atol=3e-6)
    assert np.all(m[:, 2] >= 0)
    pv = mf[f"pv_{dist}"]

    def pdf(d):
        k = len(d)
        return pv(_tile(wi, k), d, np.full(k, ax, f32), np.full(k, ay, f32))

    chi2_test(m, pdf, theta_edges_for(min(ax, ay)))


def test_g1_range_and_robustness(mf):
    n = 50_000
    v = sph(np.arccos(RNG.uniform(-1, 1, n)), RNG.uniform(0, 2 * np.pi, n))
    m = sph(np.arccos(RNG.uniform(0, 1, n)), RNG.uniform(0, 2 * np.pi, n))
    for ax, ay in [(1e-4, 1e-4), (0.3, 0.3), (1.0, 1.0), (1e-4, 1.0)]:
        A, B = np.full(n, ax, f32), np.full(n, ay, f32)
        for g in ("g1_ggx", "g1_beckmann"):
            r = mf[g](v, m, A, B)
            assert np.all((r >= 0) & (r <= 1)), g
        for d in ("d_ggx", "d_beckmann"):
            r = mf[d](m, A, B)
            assert np.all(np.isfinite(r) & (r >= 0)), d
    # grazing directions and normal incidence
    edge = np.array([[1, 0, 0], [0, 0, 1], [0.6, 0.8, 0], [0, 1, 1e-7]], f32)
    for ax in (1e-4, 1.0):
        A = np.full(len(edge), ax, f32)
        for k in ("d_ggx", "d_beckmann"):
            assert np.all(np.isfinite(mf[k](edge, A, A)))
        for k in ("g1_ggx", "g1_beckmann"):
            assert np.all(np.isfinite(mf[k](edge, edge[[1, 1, 1, 1]], A, A)))


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_visible_sampling_robust(mf, dist):
    """Extreme roughness and grazing incidence give unit normals and finite densities."""
    n = 4096
    for alpha in (1e-4, 1e-3, 1.0):
        for theta_i in (0.0, 1e-4, 1.5, 1.5707):
            wi = _wi(theta_i)
            A = np.full(n, alpha, f32)
            u = np.concatenate([uniform2(n - 4), [[0, 0], [1, 1], [0, 1], [1, 0]]]).astype(f32)
            m = mf[f"s_{dist}"](_tile(wi, n), A, A, u)
            assert np.all(np.isfinite(m)), (alpha, theta_i)
            np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1, atol=1e-5)
            p = mf[f"pv_{dist}"](_tile(wi, n), m, A, A)
            assert np.all(np.isfinite(p) & (p >= 0)), (alpha, theta_i)


def test_host_matches_scalar(mf):
    """The vectorized build (masked Newton loop of the Beckmann sampler included) agrees."""
    host = rdsl.jit(MF_SRC, target="host")
    n = 4099
    wi = sph(RNG.uniform(0, 1.56, n), RNG.uniform(0, 2 * np.pi, n))
    a = RNG.uniform(0.01, 1, n).astype(f32)
    b = RNG.uniform(0.01, 1, n).astype(f32)
    u = uniform2(n)
    for name in ("s_ggx", "s_beckmann"):
        m = mf[name](wi, a, b, u)
        np.testing.assert_allclose(host[name](wi, a, b, u), m, rtol=1e-6, atol=1e-7,
                                   err_msg=name)
        p = "pv_" + name[2:]
        np.testing.assert_allclose(host[p](wi, m, a, b), mf[p](wi, m, a, b), rtol=1e-6,
                                   err_msg=p)


def test_isotropic_overloads(mf):
    n = 1000
    wi = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 6.28, n))
    m = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 6.28, n))
    out = mf["iso_consistent"](wi, m, np.full(n, 0.3, f32), uniform2(n))
    np.testing.assert_array_equal(out, 0)


def test_smith_g_separable(mf):
    n = 1000
    wi = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 6.28, n))
    wo = sph(RNG.uniform(0, 1.5, n), RNG.uniform(0, 6.28, n))
    h = wi.astype(np.float64) + wo
    m = (h / np.linalg.norm(h, axis=1, keepdims=True)).astype(f32)
    a = np.full(n, 0.4, f32)
    g = mf["g_ggx"](wi, wo, m, a)
    ref = mf["g1_ggx"](wi, m, a, a) * mf["g1_ggx"](wo, m, a, a)
    np.testing.assert_allclose(g, ref, rtol=1e-6)


# ---------------------------------------------------------------------------- Fresnel

def fresnel_dielectric_ref(cos_i: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """Textbook unpolarized Fresnel reflectance (float64), with TIR."""
    cos_i = cos_i.astype(np.float64)
    eta = eta.astype(np.float64)
    eta = np.where(cos_i >= 0, eta, 1 / eta)
    ci = np.abs(cos_i)
    sin2_t = (1 - ci * ci) / (eta * eta)
    ct = np.sqrt(np.maximum(1 - sin2_t, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (ci - eta * ct) / (ci + eta * ct)
        rp = (eta * ci - ct) / (eta * ci + ct)
    f = 0.5 * (rs * rs + rp * rp)
    f = np.where(sin2_t >= 1, 1.0, f)
    return np.where(np.isnan(f), 1.0, f)


def fresnel_conductor_ref(cos_i: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Unpolarized reflectance of a complex IOR with numpy complex arithmetic (float64)."""
    n = eta.astype(np.float64) + 1j * k.astype(np.float64)
    ci = cos_i.astype(np.float64)
    ct = np.sqrt(1 - (1 - ci * ci) / (n * n))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (ci - n * ct) / (ci + n * ct)
        rp = (n * ci - ct) / (n * ci + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def test_fresnel_dielectric(fres):
    cos_i = np.concatenate([np.linspace(-1, 1, 2001), [0.0, 1e-7, -1e-7, 1.0, -1.0]])
    for eta in (1.5, 1.33, 2.4, 0.67, 1.0001, 1.0, 0.9999):
        c = cos_i.astype(f32)
        e = np.full(len(c), eta, f32)
        out = fres["fd"](c, e)
        assert np.all(np.isfinite(out)), eta
        f = out[:, 0]
        assert np.all((f >= 0) & (f <= 1)), eta
        ref = fresnel_dielectric_ref(c, e)
        # away from grazing, and from the critical angle where dF/dcos is unbounded
        sin_crit = min(eta, 1 / eta)
        cos_crit = np.sqrt(1 - sin_crit * sin_crit)
        inner = (np.abs(c) > 1e-3) & (np.abs(np.abs(c) - cos_crit) > 5e-3)
        np.testing.assert_allclose(f[inner], ref[inner], atol=2e-5, err_msg=str(eta))
        # eta_it / eta_ti and the sign of cos_theta_t
        out_side = c >= 0
        np.testing.assert_allclose(out[:, 2], np.where(out_side, eta, 1 / f32(eta)), rtol=1e-6)
        np.testing.assert_allclose(out[:, 2] * out[:, 3], 1.0, rtol=1e-6)
        assert np.all((out[:, 1] <= 0)[out_side]) and np.all((out[:, 1] >= 0)[~out_side])
        # Snell: sin_t = sin_i * eta_ti where there is no total internal reflection
        tir = f == 1.0
        sin_i = np.sqrt(np.maximum(0, 1 - c.astype(np.float64) ** 2))
        sin_t = np.sqrt(np.maximum(0, 1 - out[:, 1].astype(np.float64) ** 2))
        np.testing.assert_allclose(sin_t[~tir], (sin_i * out[:, 3])[~tir], atol=2e-3)
    assert fres["fd"](np.array([0.3], f32), np.array([1.0], f32))[0, 0] == 0


def test_fresnel_conductor(fres):
    cos_i = np.concatenate([np.linspace(0, 1, 1001), [1e-7, 1e-4]]).astype(f32)
    for eta, k in [(0.2, 3.9), (1.1, 0.0), (0.0, 1.0), (2.5, 0.5), (1.0, 0.0), (1.0001, 1e-4),
                   (0.05, 6.0), (4.0, 8.0)]:
        e = np.full(len(cos_i), eta, f32)
        kk = np.full(len(cos_i), k, f32)
        f = fres["fc"](cos_i, e, kk)
        assert np.all(np.isfinite(f) & (f >= 0) & (f <= 1 + 1e-6)), (eta, k)
        ref = fresnel_conductor_ref(cos_i, e, kk)
        ok = cos_i > 1e-3
        np.testing.assert_allclose(f[ok], ref[ok], atol=3e-4, err_msg=str((eta, k)))
    # a perfect mirror (Mitsuba's default roughconductor) reflects everything
    np.testing.assert_allclose(fres["fc"](cos_i, np.zeros_like(cos_i), np.ones_like(cos_i)), 1,
                               atol=1e-6)


def test_fresnel_conductor_spectrum(fres):
    n = 500
    cos_i = RNG.uniform(0, 1, n).astype(f32)
    eta = RNG.uniform(0.1, 3, (n, 3)).astype(f32)
    k = RNG.uniform(0, 5, (n, 3)).astype(f32)
    rgb = np.asarray(fres["fc_rgb"](cos_i, eta, k)).reshape(n, -1)
    for c in range(rgb.shape[1]):
        np.testing.assert_allclose(rgb[:, c], fres["fc"](cos_i, eta[:, c], k[:, c]), rtol=1e-6)
