"""Gathers of a record's fields at indices from memory are one masked 4-wide load per lane
and a transpose (compiler/backends/llvm_records.py): the values are those of a lane-by-lane
run, on active lanes, inactive lanes and a masked tail; a record that ends where the
buffer's memory ends is read without touching the page after it; a store between two
fields' reads splits the group, so the second read sees the store; the lowered kernel
has the loads instead of the gathers; and scenes rendered by the full tier (the only one
with record loads) give the bit-identical table's images (tests/test_bit_identical.py)."""

from __future__ import annotations

import ctypes
import json
import mmap

import numpy as np
import pytest
import rdsl
from rdsl.compiler.backends.llvm import lower_module
from rdsl.compiler.build import Build
from rdsl.compiler.driver import compile_kernels
from rdsl.compiler.targets import TARGETS, host_supports

SRC = """
fn vertex(j: Int, F: [Int], P: [Float], W: [Int]) -> Float {
    var out = -1.0;
    if j % 5 != 2 {
        let i = F[j];                 // an index from memory, scattered
        let p = Vec3(P[3 * i], P[i * 3 + 1], P[3 * i + 2]);
        let g = W[4 * i + 3] - W[4 * i + 1];
        out = p.x + 2.0 * p.y + 4.0 * p.z + Float(g);
    }
    return out;
}
fn uv_gap(j: Int, F: [Int], UV: [Float]) -> Float {
    let i = F[j];
    return UV[2 * i + 1] - UV[2 * i] + UV[2 * i + 3];   // a window of 4 with a gap
}
fn store_between(j: Int, F: [Int], P: [Float]) -> Float {
    let i = F[j];
    let x = P[3 * i];
    P[3 * i + 1] = x + 100.0;
    return x + P[3 * i + 1];         // must read the value just stored
}
"""
N = 203  # not a multiple of any width: a masked tail too
VECTOR = [t for t in ("sse4", "avx2", "avx512") if host_supports(TARGETS[t])]
F32 = np.float32


def _inputs(nv: int, seed: int):
    rng = np.random.default_rng(seed)
    F = rng.integers(0, nv, N).astype(np.int32)
    F[:8] = nv - 1  # the last record, in the first packet of every width
    P = rng.random(3 * nv).astype(F32)
    W = rng.integers(-50, 50, 4 * nv).astype(np.int32)
    return F, P, W


def _vertex_want(F, P, W):
    j = np.arange(N)
    i = F
    v = P[3 * i] + F32(2) * P[3 * i + 1] + F32(4) * P[3 * i + 2] \
        + (W[4 * i + 3] - W[4 * i + 1]).astype(F32)
    return np.where(j % 5 != 2, v, F32(-1)).astype(F32)


@pytest.mark.parametrize("target", ["scalar", *VECTOR])
def test_record_fields_as_gathers_read_them(target):
    mod = rdsl.jit(SRC, target=target)
    F, P, W = _inputs(57, 1)
    j = np.arange(N, dtype=np.int32)
    np.testing.assert_array_equal(np.asarray(mod.vertex(j, F, P, W)), _vertex_want(F, P, W))
    UV = np.random.default_rng(2).random(2 * 58).astype(F32)
    F2 = np.minimum(F, 56)
    want = UV[2 * F2 + 1] - UV[2 * F2] + UV[2 * F2 + 3]
    np.testing.assert_array_equal(np.asarray(mod.uv_gap(j, F2, UV)), want)


@pytest.mark.parametrize("target", ["scalar", *VECTOR])
def test_a_store_between_two_fields_is_seen(target):
    mod = rdsl.jit(SRC, target=target)
    rng = np.random.default_rng(4)
    F = rng.permutation(N).astype(np.int32)  # distinct records: no lane sees another's store
    P = rng.random(3 * N).astype(F32)
    x = P[3 * F].copy()
    got = np.asarray(mod.store_between(np.arange(N, dtype=np.int32), F, P))
    np.testing.assert_array_equal(got, x + (x + F32(100)))


def _guarded(n: int, dtype) -> tuple[np.ndarray, mmap.mmap]:
    """An array of ``n`` elements whose last byte is the last of a readable page, the next
    page PROT_NONE (a read past the array's end faults)."""
    page = mmap.PAGESIZE
    size = n * np.dtype(dtype).itemsize
    pages = -(-size // page)
    m = mmap.mmap(-1, (pages + 1) * page)
    libc = ctypes.CDLL(None, use_errno=True)
    addr = ctypes.addressof(ctypes.c_char.from_buffer(m))
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    if libc.mprotect(ctypes.c_void_p(addr + pages * page), page, 0) != 0:
        pytest.skip("mprotect refused a guard page")
    start = pages * page - size
    return np.frombuffer(m, dtype=dtype, count=n, offset=start), m


@pytest.mark.parametrize("target", [t for t in VECTOR if t != "sse4"])
def test_the_last_record_is_read_without_reading_past_it(target):
    # the last vertex's z is the buffer's last float: a 4-wide load would fault on its 4th
    mod = rdsl.jit(SRC, target=target)
    nv = 1024  # 12 KiB of P, 16 KiB of W: each ends at a page's end
    F, P0, W0 = _inputs(nv, 5)
    P, keep_p = _guarded(3 * nv, F32)
    W, keep_w = _guarded(4 * nv, np.int32)
    P[:] = P0
    W[:] = W0
    j = np.arange(N, dtype=np.int32)
    np.testing.assert_array_equal(np.asarray(mod.vertex(j, F, P, W)),
                                  _vertex_want(F, P0, W0))
    del P, W
    keep_p.close()
    keep_w.close()


@pytest.mark.parametrize("target", [t for t in ("avx2", "avx512")])
def test_one_load_per_lane_instead_of_a_gather_per_field(target):
    module, _ = compile_kernels(SRC, Build.of(target))
    llvm = str(lower_module(module, target))
    width = TARGETS[target].width

    def body(name):
        b = llvm[llvm.index(f"rdsl.body.{name}\""):]
        return [line for line in b[:b.index("\n}\n")].splitlines() if " call " in line]

    calls = body("vertex")
    # F[j] is not from memory (a plain gather or the consecutive check's load); P's three
    # fields are one group, W's two another: a masked 4-wide load per lane each
    assert sum("llvm.masked.gather" in c and "v4" not in c for c in calls) == 1
    assert sum("llvm.masked.load.v4f32" in c for c in calls) == width
    assert sum("llvm.masked.load.v4i32" in c for c in calls) == width
    calls = body("store_between")  # the store splits P's fields: two gathers stay
    assert sum("llvm.masked.gather" in c for c in calls) == 3
    assert not any("llvm.masked.load.v4" in c for c in calls)


@pytest.mark.parametrize("case", ["cbox/rgb/specialized", "cbox/rgb/generic",
                                  "materials/rgb/specialized"])
def test_full_tier_scenes_render_the_recorded_images(case, monkeypatch):
    pytest.importorskip("rdsl.runtime.embree")
    import test_bit_identical as bit
    from rdsl.runtime.render import renderer

    target = bit._host_target()
    if target is None:
        pytest.skip(f"this machine runs none of {bit.TARGETS}, the targets the hashes cover")
    name, variant, build = case.split("/")
    path = {"cbox": bit.CBOX, "materials": bit.MATERIALS}[name]
    monkeypatch.setattr(renderer, "QUICK_SAMPLES", 0)  # every render at the full tier
    want = json.loads(bit.TABLE.read_text())[bit.key(name, variant, build == "specialized",
                                                      target)]
    assert bit.render_hash(path, variant, build == "specialized", target) == want
