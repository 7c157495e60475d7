"""What the SIMD C backend prints as x86 intrinsics where ``cc`` targets them, and as
portable vector code elsewhere, with the same results.  Gathers (``RDSL_GATHER32``): a
varying load of 4-byte elements at i32 indices is one gather instruction under AVX2 (widths
4, 8) or AVX-512 (width 16), a lane loop elsewhere; both load the active lanes only (an
inactive lane's index may lie far outside the buffer) and give 0 in the others; scatters
(``RDSL_SCATTER32``) likewise under AVX-512, lane 0 first as the loop.  f32
min/max (``RDSL_MINF``/``RDSL_MAXF``): minps/maxps, which are the IR's select(a < b, a, b)
bit for bit, NaNs and signed zeros included.  And ``$RDSL_CFLAGS``, the extra flags of
``cc`` (bench/targets.py builds its c row with ``-O3``)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.backends.c_build import CFLAGS, build_c_library, compile_shared
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import compile_kernels
from rdsl.compiler.targets import get_target, host_supports

pytestmark = pytest.mark.skipif(shutil.which("cc") is None,
                                reason="no C compiler (cc) on PATH")

SRC = """
fn pick(table: [Float], ids: [Int], i: Int) -> Float {
    var r = -1.0;
    if i >= 0 && i < 64 {
        r = table[i] + Float(ids[63 - i]);
    }
    return r;
}
"""
PORTABLE = tuple(f for f in CFLAGS if not f.startswith("-march="))  # no AVX2: the loop


def build(tmp: Path, width: int, flags: tuple[str, ...], source: str = SRC
          ) -> tuple[rdsl.Module, Path]:
    src = tmp / "kernels.rdsl"
    src.write_text(source)
    module, _ = compile_kernels(src, Build.of("c", "rgb", width))
    stem = f"k{width}_{len(flags)}"
    paths = build_c_library(module, get_target("c", width), tmp, stem, source_only=True)
    compile_shared(paths["c"], tmp / f"{stem}.so", flags)
    return rdsl.load(tmp / f"{stem}.so"), paths["c"]


def expected(table: np.ndarray, ids: np.ndarray, i: np.ndarray) -> np.ndarray:
    ok = (i >= 0) & (i < 64)
    k = np.where(ok, i, 0)
    return np.where(ok, table[k] + ids[63 - k].astype(np.float32), np.float32(-1.0))


@pytest.mark.parametrize("width", [4, 8, 16])
@pytest.mark.parametrize("flags", [CFLAGS, PORTABLE], ids=["native", "portable"])
def test_masked_gather_loads_active_lanes_only(width: int, flags, tmp_path: Path):
    rng = np.random.default_rng(width)
    table = rng.random(64, dtype=np.float32)
    ids = rng.integers(-1000, 1000, 64).astype(np.int32)
    n = 1001  # a tail of n % width lanes as well
    i = rng.integers(0, 64, n).astype(np.int32)
    far = rng.random(n) < 0.4  # inactive lanes with indices ~8 GiB away either side
    i[far] = rng.choice(np.array([-(1 << 31), -(1 << 30), 1 << 30, (1 << 31) - 1]),
                        far.sum())
    mod, c_path = build(tmp_path, width, flags)
    assert "RDSL_GATHER32(" in c_path.read_text()
    got = mod["pick"](table, ids, i)
    assert np.array_equal(got, expected(table, ids, i))


SCATTER = """
fn put(out: [Float], ids: [Int], i: Int, x: Float) {
    if x > 0.0 {
        out[i] = x;
        ids[i] = i;
    }
}
"""


@pytest.mark.parametrize("width", [4, 8, 16])
@pytest.mark.parametrize("flags", [CFLAGS, PORTABLE], ids=["native", "portable"])
def test_masked_scatter_stores_active_lanes_in_order(width: int, flags, tmp_path: Path):
    rng = np.random.default_rng(width)
    n = 1001
    i = rng.integers(0, 16, n).astype(np.int32)  # many lanes of a vector to one slot
    x = rng.standard_normal(n).astype(np.float32)
    off = x <= 0  # inactive lanes with indices ~8 GiB away
    i[off] = rng.choice(np.array([-(1 << 31), (1 << 31) - 1]), off.sum())
    out, ids = np.full(16, -5.0, np.float32), np.full(16, -5, np.int32)
    want, want_ids = out.copy(), ids.copy()
    for k in range(n):  # element by element: the last store to a slot wins
        if x[k] > 0:
            want[i[k]], want_ids[i[k]] = x[k], i[k]
    mod, c_path = build(tmp_path, width, flags, SCATTER)
    assert "RDSL_SCATTER32(" in c_path.read_text()
    mod["put"](out, ids, i, x, threads=1)
    assert np.array_equal(out, want) and np.array_equal(ids, want_ids)


MINMAX = """
fn lo(a: Float, b: Float) -> Float { return min(a, b); }
fn hi(a: Float, b: Float) -> Float { return max(a, b); }
"""


@pytest.mark.parametrize("width", [4, 8, 16])
@pytest.mark.parametrize("flags", [CFLAGS, PORTABLE], ids=["native", "portable"])
def test_float_min_max_are_the_irs_selects(width: int, flags, tmp_path: Path):
    special = np.array([np.nan, -0.0, 0.0, 1.0, -1.0, np.inf, -np.inf, 1e-45],
                       np.float32)
    a, b = (x.ravel() for x in np.meshgrid(special, special))
    mod, c_path = build(tmp_path, width, flags, MINMAX)
    assert "RDSL_MINF(" in c_path.read_text() and "RDSL_MAXF(" in c_path.read_text()
    for name, want in (("lo", np.where(a < b, a, b)), ("hi", np.where(a > b, a, b))):
        got = mod[name](a, b)
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), name


@pytest.mark.skipif(shutil.which("objdump") is None, reason="no objdump on PATH")
@pytest.mark.parametrize("width,isa", [(4, "avx2"), (8, "avx2"), (16, "avx512")])
def test_gather_is_one_instruction_where_the_isa_has_it(width: int, isa: str,
                                                         tmp_path: Path):
    if not host_supports(get_target(isa)):
        pytest.skip(f"this CPU has no {isa}: -march=native builds the lane loop")

    def gathers(flags: tuple[str, ...]) -> int:
        mod, _ = build(tmp_path, width, flags)
        asm = subprocess.run(["objdump", "-d", str(mod.path)], capture_output=True,
                             text=True, check=True).stdout
        return asm.count("vpgatherdd")

    assert gathers(CFLAGS) >= 2  # the table's and the ids' loads
    assert gathers(PORTABLE) == 0


@pytest.mark.skipif(shutil.which("objdump") is None, reason="no objdump on PATH")
@pytest.mark.parametrize("width", [4, 8, 16])
def test_scatter_is_one_instruction_under_avx512(width: int, tmp_path: Path):
    if not host_supports(get_target("avx512")):
        pytest.skip("this CPU has no AVX-512: -march=native builds the lane loop")
    mod, _ = build(tmp_path, width, CFLAGS, SCATTER)
    asm = subprocess.run(["objdump", "-d", str(mod.path)], capture_output=True, text=True,
                         check=True).stdout
    assert asm.count("vpscatterdd") >= 2  # out's and ids' stores


def test_rdsl_cflags_are_added_and_keyed(tmp_path: Path, monkeypatch):
    """``RDSL_CFLAGS`` follows the default flags (a later ``-O3`` wins), the manifest
    records them, the kernel cache keeps the build apart, and a flag cc refuses is a
    diagnostic naming it."""
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    table, ids = np.arange(64, dtype=np.float32), np.zeros(64, np.int32)
    i = np.arange(-8, 72, dtype=np.int32)
    plain = rdsl.jit(SRC, target="c", width=8)
    monkeypatch.setenv("RDSL_CFLAGS", "-O3 -fno-unroll-loops")
    tuned = rdsl.jit(SRC, target="c", width=8)
    assert tuned.path != plain.path and not tuned.from_cache
    assert tuned.manifest["cflags"][-2:] == ["-O3", "-fno-unroll-loops"]
    assert "-O3" not in plain.manifest["cflags"]
    assert np.array_equal(tuned["pick"](table, ids, i), plain["pick"](table, ids, i))
    monkeypatch.setenv("RDSL_CFLAGS", "-fno-such-flag-rdsl")
    with pytest.raises(CompileError, match="-fno-such-flag-rdsl"):
        rdsl.jit(SRC, target="c", width=8)
