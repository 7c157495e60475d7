"""Embree 4: hits agree with a brute-force Möller–Trumbore intersector, packet widths agree
with each other, the struct layouts match what Embree writes, and compiled code (MCJIT and a
linked ``.so``) calls ``rtcIntersectN``/``rtcOccludedN`` with no Python per ray."""

from __future__ import annotations

import ctypes
import shutil
import subprocess

import numpy as np
import pytest
from rdsl.compiler.backends import embree_llvm as LL
from rdsl.core import embree_abi as ABI
from rdsl.runtime import embree as E

try:
    E.load_embree()
except E.EmbreeError as _e:  # pragma: no cover - depends on the environment
    pytest.skip(f"Embree 4 is unavailable: {_e}", allow_module_level=True)

# --------------------------------------------------------------------------- reference


def brute_force(verts: np.ndarray, faces: np.ndarray, o: np.ndarray, d: np.ndarray,
                tmax: np.ndarray, eps: float = 1e-5) -> dict[str, np.ndarray]:
    """Möller–Trumbore in float64 against every triangle.

    Returns the closest ``t`` (inf on a miss), its primitive, the second-closest ``t`` (to
    spot near-ties) and ``grazing``: the ray passes within ``eps`` (in barycentrics) of some
    triangle's edge, where float32 intersectors may legitimately disagree."""
    v = verts.astype(np.float64)[faces]  # (M, 3, 3)
    v0, e1, e2 = v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    o64, d64 = o.astype(np.float64)[:, None], d.astype(np.float64)[:, None]  # (N, 1, 3)
    p = np.cross(d64, e2)
    det = np.einsum("nmk,mk->nm", p, e1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = o64 - v0
        u = np.einsum("nmk,nmk->nm", s, p) * inv
        q = np.cross(s, e1)
        w = np.einsum("nk,nmk->nm", d64[:, 0], q) * inv
        t = np.einsum("mk,nmk->nm", e2, q) * inv
    in_range = (t >= 0) & (t <= tmax[:, None].astype(np.float64)) & (np.abs(det) > 1e-12)
    margin = np.minimum(np.minimum(u, w), 1 - u - w)
    hit = in_range & (margin >= 0)
    grazing = (in_range & (np.abs(margin) < eps)).any(axis=1)
    grazing |= ((np.abs(det) <= 1e-9) & (np.abs(margin) < 1)).any(axis=1)  # edge-on
    tt = np.where(hit, t, np.inf)
    order = np.argsort(tt, axis=1)
    rows = np.arange(len(o))
    best, second = tt[rows, order[:, 0]], (tt[rows, order[:, 1]] if tt.shape[1] > 1
                                            else np.full(len(o), np.inf))
    return {"t": best, "prim": np.where(np.isfinite(best), order[:, 0], -1),
            "second": second, "grazing": grazing}


def random_soup(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray]:
    centers = rng.uniform(-1, 1, (m, 1, 3))
    verts = (centers + rng.normal(0, 0.25, (m, 3, 3))).reshape(-1, 3).astype(np.float32)
    return verts, np.arange(3 * m, dtype=np.uint32).reshape(m, 3)


def cube() -> tuple[np.ndarray, np.ndarray]:
    verts = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)],
                     dtype=np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    faces = [tri for a, b, c, dd in quads for tri in ((a, b, c), (a, c, dd))]
    return verts, np.array(faces, dtype=np.uint32)


def random_rays(rng: np.random.Generator, n: int, spread: float = 2.5
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    o = rng.uniform(-spread, spread, (n, 3)).astype(np.float32)
    target = rng.uniform(-1, 1, (n, 3))
    d = (target - o).astype(np.float32)
    d *= rng.uniform(0.5, 2.0, (n, 1)).astype(np.float32)  # unnormalized directions
    tmax = np.where(rng.random(n) < 0.25, rng.uniform(0.1, 1.0, n), np.inf).astype(np.float32)
    return o, d, tmax


def compare(scene: E.EmbreeScene, verts: np.ndarray, faces: np.ndarray, o: np.ndarray,
            d: np.ndarray, tmax: np.ndarray) -> None:
    ref = brute_force(verts, faces, o, d, tmax)
    got = scene.intersect(o, d, tmax)
    ok = ~ref["grazing"]
    assert ok.mean() > 0.97, "too many grazing rays for a meaningful test"
    assert ref["prim"][ok].__ge__(0).sum() > 0.2 * ok.sum(), "too few hits"
    np.testing.assert_array_equal(got["hit"][ok], ref["prim"][ok] >= 0)
    h = ok & got["hit"]
    np.testing.assert_allclose(got["t"][h], ref["t"][h], rtol=1e-4)
    with np.errstate(invalid="ignore"):  # inf - inf on misses
        tie = np.abs(ref["second"] - ref["t"]) <= 1e-5 * np.abs(ref["t"])
    np.testing.assert_array_equal(got["prim_id"][h & ~tie], ref["prim"][h & ~tie])
    assert np.all(got["geom_id"][got["hit"]] == 0) and np.all(got["geom_id"][~got["hit"]] == -1)
    # the reported point lies on the reported triangle: u, v are Embree's barycentrics
    tri = verts.astype(np.float64)[faces[got["prim_id"][h]]]
    u, v = got["u"][h, None], got["v"][h, None]
    p = (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
    np.testing.assert_allclose(p, o[h] + got["t"][h, None] * d[h], atol=2e-4)
    # Ng is (v1 - v0) x (v2 - v0)
    ng = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    np.testing.assert_allclose(got["ng"][h], ng, rtol=1e-4, atol=1e-5)
    occ = scene.occluded(o, d, tmax)
    np.testing.assert_array_equal(occ[ok], ref["prim"][ok] >= 0)


@pytest.fixture(scope="module")
def soup() -> tuple[E.EmbreeScene, np.ndarray, np.ndarray]:
    verts, faces = random_soup(np.random.default_rng(1), 150)
    return E.EmbreeScene([(verts, faces)]), verts, faces


def test_soup_matches_brute_force(soup):
    scene, verts, faces = soup
    compare(scene, verts, faces, *random_rays(np.random.default_rng(2), 3000))


def test_cube_matches_brute_force():
    verts, faces = cube()
    rng = np.random.default_rng(3)
    with E.EmbreeScene([(verts, faces)], quality="high", robust=True) as scene:
        compare(scene, verts, faces, *random_rays(rng, 2000, spread=3.0))
        o_in = rng.uniform(-0.9, 0.9, (500, 3)).astype(np.float32)  # every ray exits
        d_in = rng.normal(size=(500, 3)).astype(np.float32)
        assert scene.intersect(o_in, d_in)["hit"].all()
        compare(scene, verts, faces, o_in, d_in, np.full(500, np.inf, np.float32))
    assert scene.handle is None


def test_two_level_scene_matches_brute_force(soup):
    _, verts, faces = soup
    half = len(faces) // 2  # two meshes sharing the vertices, under a BVH over the meshes
    with E.EmbreeScene([(verts, faces[:half]), (verts, faces[half:])], quality="low",
                       mesh_quality="high") as scene:
        rays = random_rays(np.random.default_rng(4), 2000)
        hits = scene.intersect(*rays)
        both = E.EmbreeScene([(verts, faces)]).intersect(*rays)
        np.testing.assert_array_equal(hits["hit"], both["hit"])
        np.testing.assert_array_equal(hits["t"], both["t"])
    with pytest.raises(ValueError, match="mesh_quality: expected one of"):
        E.EmbreeScene([cube()], mesh_quality="best")


def test_several_meshes_and_tmin():
    v, f = cube()
    scene = E.EmbreeScene([(v, f), (v + np.float32(5), f.astype(np.int64))])
    o = np.array([[5, 5, 10], [0, 0, 10], [0, 0, 10], [20, 20, 20]], np.float32)
    d = np.array([[0, 0, -1]] * 4, np.float32)
    r = scene.intersect(o, d, tmin=np.array([0, 0, 9.5, 0], np.float32))
    np.testing.assert_array_equal(r["geom_id"], [1, 0, 0, -1])
    # Embree's float ray-triangle test: a few ulps off the exact distance, and which ulps
    # depends on the ISA it picks for the host (an AVX2 host gives 8.999999 for 9)
    np.testing.assert_allclose(r["t"][:3], [4, 9, 11], rtol=1e-6)
    assert r["t"][3] == np.inf
    np.testing.assert_array_equal(scene.occluded(o, d, 9.0), [True, True, True, False])
    np.testing.assert_array_equal(scene.occluded(o, d, np.array([3.9, 8.9, 11.5, 1e9])),
                                  [False, False, True, False])
    assert "2 meshes, 24 triangles" in repr(scene)
    single = E.EmbreeScene((v, f))  # one (vertices, faces) pair on its own
    assert single.intersect(o[1:2], d[1:2])["prim_id"][0] >= 0


@pytest.mark.parametrize("width", [1, 4, 8])
def test_widths_agree(soup, width):
    scene, _, _ = soup
    o, d, tmax = random_rays(np.random.default_rng(4), 1001)  # not a multiple of any width
    ref, got = scene.intersect(o, d, tmax, width=16), scene.intersect(o, d, tmax, width=width)
    for k in ("hit", "prim_id", "geom_id"):
        np.testing.assert_array_equal(got[k], ref[k])
    for k in ("t", "u", "v", "ng"):
        np.testing.assert_allclose(got[k], ref[k], rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(scene.occluded(o, d, tmax, width=width),
                                  scene.occluded(o, d, tmax, width=16))


def test_empty_batch(soup):
    scene, _, _ = soup
    r = scene.intersect(np.zeros((0, 3)), np.zeros((0, 3)))
    assert r["t"].shape == (0,) and r["ng"].shape == (0, 3)
    assert scene.occluded(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


# --------------------------------------------------------------------------- layout


@pytest.mark.parametrize("width", ABI.WIDTHS)
def test_layout_matches_what_embree_writes(soup, width):
    """Fill a packet and a guard zone with sentinels: Embree must write exactly the hit
    fields our layout names (instID and instPrimID included) and nothing past the end."""
    scene, verts, faces = soup
    lay = ABI.PacketLayout(width)
    sentinel = 0x5A5A5A5A
    words = E._aligned_words(lay.words + 64, lay.align)
    words[:] = sentinel
    f = words.view(np.float32)
    c = verts[faces[0]].mean(axis=0)
    for lane in range(width):
        for k, a in enumerate("xyz"):
            f[lay.offset(f"org_{a}") + lane] = c[k] + (5.0 if a == "z" else 0.0)
            f[lay.offset(f"dir_{a}") + lane] = -1.0 if a == "z" else 0.0
        f[lay.offset("tnear") + lane], f[lay.offset("time") + lane] = 0.0, 0.0
        f[lay.offset("tfar") + lane] = np.inf
        words[lay.offset("mask") + lane] = 0xFFFFFFFF
        words[lay.offset("id") + lane], words[lay.offset("flags") + lane] = lane, 0
        words[lay.offset("geomID") + lane] = ABI.RTC_INVALID_GEOMETRY_ID
    valid = E._aligned_words(max(width, 4), lay.align).view(np.int32)
    valid[:] = -1
    fn = getattr(scene.lib, f"rtcIntersect{width}")
    if width == 1:
        fn(scene.handle, words.ctypes.data, None)
    else:
        fn(valid.ctypes.data, scene.handle, words.ctypes.data, None)
    scene.device.check("rtcIntersect")
    for lane in range(width):
        assert words[lay.offset("geomID") + lane] == 0
        assert words[lay.offset("instID") + lane] == ABI.RTC_INVALID_GEOMETRY_ID
        assert words[lay.offset("instPrimID") + lane] == ABI.RTC_INVALID_GEOMETRY_ID
        assert np.isfinite(f[lay.offset("tfar") + lane])
    end = lay.offset("instPrimID") + width
    assert np.all(words[end:] == sentinel), "Embree wrote past the fields we know of"


@pytest.mark.parametrize("width", ABI.WIDTHS)
def test_llvm_types_have_embree_layout(width):
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    td = llvm.create_target_data("e-m:e-p270:32:32-p271:32:32-p272:64:64-i64:64-i128:128-"
                                 "f80:128-n8:16:32:64-S128")
    lay, ty = ABI.PacketLayout(width), LL.llvm_rayhit_type(width)
    assert ty.get_abi_size(td) == lay.nbytes == {1: 96, 4: 336, 8: 672, 16: 1344}[width]
    assert LL.llvm_ray_type(width).get_abi_size(td) == ABI.PacketLayout(width, False).nbytes
    ray, hit = ty.elements
    assert ty.get_element_offset(td, 1) == 4 * lay.ray_words
    for j, name in enumerate(ABI.RAY_FIELDS):
        assert ray.get_element_offset(td, j) == 4 * lay.offset(name)
    for j, name in enumerate(ABI.HIT_FIELDS):
        assert 4 * lay.ray_words + hit.get_element_offset(td, j) == 4 * lay.offset(name)


# --------------------------------------------------------------------------- compiled code


def build_tracer(query: str, width: int):
    """``void f(ptr scene, ptr o, ptr d, ptr tout, ptr pout, i32 n)`` in LLVM IR.

    Loops over packets of ``width`` rays; each packet is filled on the stack and traced with
    one ``rtc<query><width>`` call. Intersect writes t (inf on a miss) and primID (-1);
    Occluded writes tfar (-inf when occluded)."""
    import llvmlite.ir as L

    f32, i32, ptr = L.FloatType(), L.IntType(32), L.PointerType()
    mod = L.Module(name=f"embree_{query}{width}")
    rtc = LL.declare_query(mod, query, width)
    fn = L.Function(mod, L.FunctionType(L.VoidType(), [ptr] * 5 + [i32]), "trace")
    scene, o, d, tout, pout, n = fn.args
    entry, head, body, done = (fn.append_basic_block(s) for s in ("entry", "head", "body",
                                                                     "done"))
    b = L.IRBuilder(entry)
    with_hit = query == "Intersect"
    pkt_ty = LL.llvm_rayhit_type(width) if with_hit else LL.llvm_ray_type(width)
    pkt = LL.alloca_packet(b, width, with_hit=with_hit, name="packet")
    valid_ty = L.ArrayType(i32, width)
    valid = b.alloca(valid_ty, name="valid")
    valid.align = ABI.PacketLayout(width).align
    valid.type = ptr  # as alloca_packet does: an opaque pointer
    b.branch(head)
    b.position_at_end(head)
    base = b.phi(i32, name="base")
    base.add_incoming(L.Constant(i32, 0), entry)
    b.cbranch(b.icmp_signed("<", base, n), body, done)
    b.position_at_end(body)

    def field(name: str, lane: int) -> L.Value:
        return b.gep(pkt, LL.field_indices(name, width, lane, with_hit=with_hit),
                     inbounds=True, source_etype=pkt_ty)

    last = b.sub(n, L.Constant(i32, 1))
    lanes = []
    for lane in range(width):
        idx = b.add(base, L.Constant(i32, lane))
        active = b.icmp_signed("<", idx, n)
        src = b.select(active, idx, last)  # inactive lanes read a valid ray and are ignored
        lanes.append((idx, active))
        for k, axis in enumerate("xyz"):
            at = b.add(b.mul(src, L.Constant(i32, 3)), L.Constant(i32, k))
            for arr, nm in ((o, "org"), (d, "dir")):
                val = b.load(b.gep(arr, [at], source_etype=f32), typ=f32)
                b.store(val, field(f"{nm}_{axis}", lane))
        for nm, val in (("tnear", L.Constant(f32, 0.0)), ("time", L.Constant(f32, 0.0)),
                        ("tfar", L.Constant(f32, float("inf"))),
                        ("mask", L.Constant(i32, -1)), ("id", idx),
                        ("flags", L.Constant(i32, 0))):
            b.store(val, field(nm, lane))
        if with_hit:
            b.store(L.Constant(i32, -1), field("geomID", lane))
        if width > 1:
            vslot = b.gep(valid, [L.Constant(i32, 0), L.Constant(i32, lane)],
                          source_etype=valid_ty)
            b.store(b.select(active, L.Constant(i32, -1), L.Constant(i32, 0)), vslot)
    null = L.Constant(ptr, None)
    b.call(rtc, [scene, pkt, null] if width == 1 else [valid, scene, pkt, null])
    for lane, (idx, active) in enumerate(lanes):
        with b.if_then(active):
            t = b.load(field("tfar", lane), typ=f32)
            if with_hit:
                geom = b.load(field("geomID", lane), typ=i32)
                miss = b.icmp_unsigned("==", geom, L.Constant(i32, -1))
                t = b.select(miss, L.Constant(f32, float("inf")), t)
                prim = b.select(miss, L.Constant(i32, -1),
                                b.load(field("primID", lane), typ=i32))
                b.store(prim, b.gep(pout, [idx], source_etype=i32))
            b.store(t, b.gep(tout, [idx], source_etype=f32))
    nxt = b.add(base, L.Constant(i32, width))
    base.add_incoming(nxt, b.block)
    b.branch(head)
    b.position_at_end(done)
    b.ret_void()
    return mod


def _target_machine():
    import llvmlite.binding as llvm

    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    target = llvm.Target.from_default_triple()
    return target.create_target_machine(cpu=llvm.get_host_cpu_name(), opt=2, reloc="pic")


def _parsed(query: str, width: int):
    import llvmlite.binding as llvm

    mod = llvm.parse_assembly(str(build_tracer(query, width)))
    mod.verify()
    return mod


_CFN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p,
                        ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int32)


def _call(fn, scene: E.EmbreeScene, o: np.ndarray, d: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray]:
    o, d = np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)
    tout, pout = np.full(len(o), np.nan, np.float32), np.full(len(o), -7, np.int32)
    fn(scene.handle, o.ctypes.data, d.ctypes.data, tout.ctypes.data, pout.ctypes.data, len(o))
    return tout, pout


@pytest.fixture(scope="module")
def jit():
    """MCJIT engines for every (query, width) pair, with Embree bound by address."""
    import llvmlite.binding as llvm

    addrs = E.bind_llvm_symbols()
    assert set(addrs) == set(ABI.QUERY_FUNCTIONS) and all(addrs.values())
    engines, fns = [], {}
    for query in ("Intersect", "Occluded"):
        for width in ABI.WIDTHS:
            ee = llvm.create_mcjit_compiler(_parsed(query, width), _target_machine())
            ee.finalize_object()
            engines.append(ee)
            fns[query, width] = _CFN(ee.get_function_address("trace"))
    yield fns
    del engines


@pytest.mark.parametrize("width", ABI.WIDTHS)
def test_jit_calls_embree(soup, jit, width):
    scene, _, _ = soup
    o, d, _ = random_rays(np.random.default_rng(5), 777)
    ref = scene.intersect(o, d)
    t, prim = _call(jit["Intersect", width], scene, o, d)
    np.testing.assert_array_equal(prim, ref["prim_id"])
    np.testing.assert_allclose(t, ref["t"], rtol=1e-6)
    tfar, _ = _call(jit["Occluded", width], scene, o, d)
    np.testing.assert_array_equal(tfar == -np.inf, scene.occluded(o, d))


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (`cc`) to link a .so")
def test_shared_library_links_against_embree(soup, tmp_path):
    scene, _, _ = soup
    tm = _target_machine()
    obj = tmp_path / "trace.o"
    obj.write_bytes(tm.emit_object(_parsed("Intersect", 8)))
    so = tmp_path / "trace.so"
    subprocess.run(["cc", "-shared", "-o", str(so), str(obj), *ABI.link_args()], check=True,
                   capture_output=True)
    if shutil.which("readelf"):
        dynamic = subprocess.run(["readelf", "-d", str(so)], check=True, capture_output=True,
                                 text=True).stdout
        assert "libembree4" in dynamic
    lib = ctypes.CDLL(str(so))
    o, d, _ = random_rays(np.random.default_rng(6), 100)
    t, prim = _call(_CFN(ctypes.cast(lib.trace, ctypes.c_void_p).value), scene, o, d)
    ref = scene.intersect(o, d)
    np.testing.assert_array_equal(prim, ref["prim_id"])
    np.testing.assert_allclose(t, ref["t"], rtol=1e-6)


# --------------------------------------------------------------------------- errors


GOOD_V, GOOD_F = cube()


@pytest.mark.parametrize("mesh, message", [
    ((GOOD_V.astype(np.complex64), GOOD_F), r"meshes\[0\]\.vertices: expected real numbers"),
    ((GOOD_V.astype(str), GOOD_F), r"meshes\[0\]\.vertices: expected real numbers"),
    ((GOOD_V[:, :2], GOOD_F), r"meshes\[0\]\.vertices: expected shape \(N, 3\)"),
    ((GOOD_V.ravel(), GOOD_F), r"meshes\[0\]\.vertices: expected shape"),
    ((np.where(GOOD_V > 0, np.nan, GOOD_V), GOOD_F), r"meshes\[0\]\.vertices: contains NaN"),
    ((GOOD_V, GOOD_F.astype(np.float32)), r"meshes\[0\]\.faces: expected integer"),
    ((GOOD_V, GOOD_F[:, :2]), r"meshes\[0\]\.faces: expected shape \(M, 3\)"),
    ((GOOD_V, GOOD_F + 1), r"meshes\[0\]\.faces: vertex index 8 is out of range for 8"),
    ((GOOD_V, GOOD_F.astype(np.int32) - 1), r"meshes\[0\]\.faces: vertex index -1"),
    ((GOOD_V, GOOD_F[:0]), r"meshes\[0\]\.faces: the mesh has no triangles"),
    ((GOOD_V,), r"meshes\[0\]: expected a \(vertices, faces\) pair"),
])
def test_bad_meshes(mesh, message):
    with pytest.raises(ValueError, match=message):
        E.EmbreeScene([(GOOD_V, GOOD_F), mesh][1:])
    with pytest.raises(ValueError, match=message.replace(r"\[0\]", r"\[1\]")):
        E.EmbreeScene([(GOOD_V, GOOD_F), mesh])


def test_bad_rays(soup):
    scene, _, _ = soup
    o = np.zeros((4, 3), np.float32)
    with pytest.raises(ValueError, match=r"origins: expected shape \(N, 3\)"):
        scene.intersect(o[:, :2], o)
    with pytest.raises(ValueError, match="dirs: expected 4 directions"):
        scene.intersect(o, o[:3])
    with pytest.raises(ValueError, match="dirs: expected real numbers"):
        scene.occluded(o, o.astype(np.complex64))
    with pytest.raises(ValueError, match="tmax: expected a number or an array of 4"):
        scene.intersect(o, o + 1, np.ones(3))
    with pytest.raises(ValueError, match="width: Embree packets are 1, 4, 8 or 16"):
        scene.intersect(o, o + 1, width=2)
    with pytest.raises(ValueError, match="quality: expected one of"):
        E.EmbreeScene([cube()], quality="best")


def test_embree_errors_become_exceptions():
    scene = E.EmbreeScene([cube()])
    dev = scene.device
    dev.lib.rtcSetSceneBuildQuality(scene.handle, 7)  # invalid: Embree reports, we raise
    with pytest.raises(E.EmbreeError, match="rtcSetSceneBuildQuality failed: RTC_ERROR_"):
        dev.check("rtcSetSceneBuildQuality")
    dev.check("nothing")  # the error was consumed
    scene.close()
    scene.close()  # idempotent
    with pytest.raises(E.EmbreeError, match="the scene was closed"):
        scene.intersect(np.zeros((1, 3)), np.ones((1, 3)))


def test_library_comes_from_the_wheel():
    path = ABI.embree_library_path()
    assert "embreex" in str(path) and path.name.startswith("libembree4")
    assert E.default_device().version // 10000 == 4
