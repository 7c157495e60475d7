"""The SIMD C backend (``--target c``): the differential corpus against the interpreter at
widths 1, 4, 8 and 16 (bit for bit: the IR has no transcendental, and the C uses only
exactly rounded libm functions); every stdlib BSDF module built with ``-Werror`` and
matching the avx2 LLVM build bit for bit on random inputs; a C host program of its own
that links the generated source and calls a kernel on an array of structures; bad input."""

from __future__ import annotations

import ctypes
import re
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
from test_cli import assert_user_error
from test_cli import rdsl as rdsl_cli
from test_differential import CASES, CORPUS, check_case, interp_modules  # noqa: F401

CC = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (cc) on PATH")
WIDTHS = (1, 4, 8, 16)
STRICT = (*CFLAGS, "-Wall", "-Wextra", "-Werror")
STDLIB_BSDFS = sorted((Path(rdsl.__file__).resolve().parent / "stdlib" / "bsdf").glob("*.rdsl"))


@pytest.fixture(scope="module")
def c_compiled():
    return {(f.stem, f"c{w}"): rdsl.jit(f, target="c", width=w)
            for w in WIDTHS for f in CORPUS.glob("*.rdsl")}


@needs_cc
@pytest.mark.xdist_group("corpus-c")  # one worker: the module fixtures build once
@pytest.mark.parametrize("case", sorted(CASES), ids=lambda c: f"{c[0]}.{c[1]}")
def test_corpus_matches_interpreter(case, interp_modules, c_compiled):  # noqa: F811
    check_case(case, interp_modules[case[0]], c_compiled)

# -- every stdlib BSDF: C (width 8, -Werror) against the avx2 LLVM build ------------------

_NP = {"f32": np.float32, "i32": np.int32, "u32": np.uint32, "u64": np.uint64,
       "bool": np.uint8}
_CT = {"f32": ctypes.c_float, "i32": ctypes.c_int32, "u32": ctypes.c_uint32,
       "u64": ctypes.c_uint64, "bool": ctypes.c_uint8}


def _random_inputs(kernel: dict, n: int, rng: np.random.Generator) -> dict:
    """Arrays for the varying args (directions in [-1, 1], samples `u*` in [0, 1)), values
    for the uniform ones, zeroed buffers."""
    out: dict = {}
    for a in kernel["args"]:
        d, name = a["dtype"], a["name"]
        if a["kind"] == "uniform":
            out[name] = 0 if d in ("i32", "u32", "u64") else 1 if d == "bool" else \
                float(rng.uniform(0.05, 0.9))
        elif a["kind"] == "varying":
            if d == "f32":
                lo = 0.0 if name.startswith("u") else -1.0
                out[name] = rng.uniform(lo, 1.0, n).astype(np.float32)
            elif d == "bool":
                out[name] = (rng.random(n) < 0.9).astype(np.uint8)
            else:
                out[name] = rng.integers(0, 4, n).astype(_NP[d])
        elif a["kind"] == "buffer":
            out[name] = np.zeros(4096, _NP[d])
    if "n_phi" in out:  # measured_polarized: a valid table, or its lookups leave T
        kinds = {a["name"]: (a["kind"], _NP[a["dtype"]]) for a in kernel["args"]}
        for name, v in _pbrdf_table_inputs().items():
            kind, dtype = kinds.get(name, ("absent", None))
            if kind in ("uniform", "buffer"):
                out[name] = v
            elif kind == "varying":
                out[name] = np.full(n, v, dtype)
    return out


def _pbrdf_table_inputs() -> dict:
    """The texel buffer and instance values of a synthetic pBRDF table, as the runtime packs
    them (runtime/render/measured.py), read at 550 nm."""
    from rdsl.tools.gen_pbrdf import synthetic_pbrdf

    t = synthetic_pbrdf(n_phi=5, n_theta_d=4, n_theta_h=6)
    grids = [t["phi_d"].ravel(), t["theta_d"].ravel(), t["theta_h"].ravel()]
    values = np.concatenate([*grids, t["wvls"].astype(np.float32), t["M"].ravel()])
    return {"T": values.astype(np.float32), "offset": 0, "n_phi": len(grids[0]),
            "n_td": len(grids[1]), "n_th": len(grids[2]), "n_wl": len(t["wvls"]),
            "wavelength": 550.0}


def _call_raw(lib: ctypes.CDLL, kernel: dict, inputs: dict, n: int) -> list[np.ndarray]:
    """Call ``rdsl_<name>`` through the C ABI of the manifest: (n, args with strides...,
    mask, mask stride); returns the outputs."""
    args: list = [ctypes.c_int64(n)]
    outs = []
    for a in kernel["args"]:
        if a["kind"] == "uniform":
            args.append(_CT[a["dtype"]](inputs[a["name"]]))
            continue
        arr = np.zeros(n, _NP[a["dtype"]]) if a["kind"] == "output" else inputs[a["name"]]
        if a["kind"] == "output":
            outs.append(arr)
        args.append(arr.ctypes.data_as(ctypes.c_void_p))
        if a["strided"]:
            args.append(ctypes.c_int64(arr.strides[0]))
    getattr(lib, kernel["symbol"])(*args, None, ctypes.c_int64(0))
    return outs


def assert_bitwise(kernel: dict, got: list[np.ndarray], want: list[np.ndarray]) -> int:
    """Assert that each output of ``kernel`` (its manifest entry) is the same bit for bit
    (NaNs as NaN); returns how many of the wanted values are nonzero."""
    outs = [a["name"] for a in kernel["args"] if a["kind"] == "output"]
    for name, g, w in zip(outs, got, want):
        assert np.array_equal(_bits(g), _bits(w)), \
            f"{kernel['name']}.{name}: {np.sum(_bits(g) != _bits(w))} of {len(w)} lanes differ"
    return sum(np.count_nonzero(w) for w in want)


def _bits(a: np.ndarray) -> np.ndarray:
    return np.where(np.isnan(a), np.float32(np.nan), a).view(np.uint32) \
        if a.dtype == np.float32 else a


@needs_cc
@pytest.mark.skipif(not host_supports(get_target("avx2")), reason="the CPU lacks AVX2")
@pytest.mark.parametrize("path", STDLIB_BSDFS, ids=lambda p: p.stem)
def test_stdlib_bsdf_matches_avx2(path: Path, tmp_path: Path):
    build = Build.of("c", "rgb", width=8)
    module, _ = compile_kernels(path, build)
    paths = build_c_library(module, build.target, tmp_path, path.stem, source_only=True)
    compile_shared(paths["c"], tmp_path / "lib.so", STRICT)  # fails on any warning
    lib = ctypes.CDLL(str(tmp_path / "lib.so"))
    ref = rdsl.jit(path, target="avx2")
    names = {k["name"].rsplit(".", 1)[-1] for k in ref.manifest["kernels"]}
    if re.search(r"^bsdf \w+", path.read_text(), re.MULTILINE):  # a plugin, not a library
        assert {"eval", "pdf", "sample"} <= names, names
    rng = np.random.default_rng(3)
    # not a multiple of 8: the tail is masked; fewer where a kernel computes roughplastic's
    # coating integrals at every call (a plugin compiled without a scene has no tables)
    n = 99 if path.stem in ("roughplastic", "common") else 999
    nonzero = 0
    for k in ref.manifest["kernels"]:
        inputs = _random_inputs(k, n, rng)
        got = _call_raw(lib, k, inputs, n)
        want = _call_raw(ref._lib, k, inputs, n)
        nonzero += assert_bitwise(k, got, want)
    # per module: a delta BSDF's eval is 0 everywhere, its sample is not
    assert nonzero > 0, "every output is 0 (a vacuous check)"


# -- a C host program: the generated header, its own array of structures -----------------

HOST_SRC = """
fn shade(a: Float, b: Float, k: Int, flag: Bool) -> Float {
    if flag { return a * b + Float(k); }
    return a - b;
}
"""

HOST_C = r"""
#include <stdio.h>
#include <stdint.h>
#include "shade.h"
typedef struct { float a; int32_t k; uint8_t flag; float b; float out; } Item;
int main(void) {
    enum { N = 37 };
    Item items[N];
    uint8_t mask[2 * N];
    for (int i = 0; i < N; ++i) {
        items[i].a = 0.37f * (float)i - 3.0f;
        items[i].b = 1.25f - 0.11f * (float)i;
        items[i].k = i % 5 - 2;
        items[i].flag = (uint8_t)(i % 3 != 0);
        items[i].out = -7.0f;
        mask[2 * i] = (uint8_t)(i % 7 != 3);
        mask[2 * i + 1] = 0;
    }
    rdsl_shade(N, &items[0].a, sizeof(Item), &items[0].b, sizeof(Item), &items[0].k,
               sizeof(Item), &items[0].flag, sizeof(Item), &items[0].out, sizeof(Item),
               mask, 2);
    for (int i = 0; i < N; ++i) printf("%a\n", (double)items[i].out);
    return 0;
}
"""


@needs_cc
@pytest.mark.parametrize("width", [1, 8])
def test_c_host_program(width: int, tmp_path: Path):
    src = tmp_path / "shade.rdsl"
    src.write_text(HOST_SRC)
    r = rdsl_cli("compile", str(src), "--target", "c", "--width", str(width), "--emit", "c",
                 "-o", str(tmp_path / "shade"))
    assert r.returncode == 0, r.stderr
    (tmp_path / "host.c").write_text(HOST_C)
    # the promise, to the letter: no optimization, no -march, every warning an error
    subprocess.run([CC, "-std=c11", "-Wall", "-Wextra", "-Werror", "-c", "shade.c", "-o",
                    "plain.o"], cwd=tmp_path, check=True)
    strict = [CC, *STRICT[:-1], "-Werror"]
    strict = [f for f in strict if f != "-fPIC"]
    subprocess.run([*strict, "-c", "shade.c", "-o", "shade.o"], cwd=tmp_path, check=True)
    subprocess.run([*strict, "host.c", "shade.o", "-lm", "-o", "host"], cwd=tmp_path,
                   check=True)
    out = subprocess.run([str(tmp_path / "host")], capture_output=True, text=True,
                         check=True).stdout.split()
    got = np.array([float.fromhex(x) for x in out], np.float32)
    i = np.arange(37)
    f = np.float32
    a = f(0.37) * i.astype(f) - f(3.0)
    b = f(1.25) - f(0.11) * i.astype(f)
    k = (i % 5 - 2).astype(f)
    want = np.where(i % 3 != 0, a * b + k, a - b).astype(f)
    want = np.where(i % 7 != 3, want, f(-7.0))  # masked lanes keep their value
    assert np.array_equal(got, want), np.nonzero(got != want)


@needs_cc
def test_cli_library_loads(tmp_path: Path):
    src = tmp_path / "shade.rdsl"
    src.write_text(HOST_SRC)
    r = rdsl_cli("compile", str(src), "--target", "c", "--width", "4", "-o",
                 str(tmp_path / "out" / "shade"))
    assert r.returncode == 0, r.stderr
    for ext in (".c", ".h", ".json", ".so"):
        assert (tmp_path / "out" / f"shade{ext}").is_file(), ext
    mod = rdsl.load(tmp_path / "out" / "shade.so")
    assert (mod.target, mod.width, mod.manifest["backend"]) == ("c", 4, "c")
    a = np.linspace(-2, 2, 11, dtype=np.float32)
    got = mod["shade"](a, a[::-1].copy(), np.full(11, 3, np.int32), np.ones(11, bool))
    assert np.array_equal(got, a * a[::-1] + np.float32(3))
    r = rdsl_cli("ir", str(src), "--target", "c", "--width", "16", "--no-locs")
    assert r.returncode == 0 and "f32x16" in r.stdout, r.stderr


# -- bad input ----------------------------------------------------------------------------


def test_unknown_width(tmp_path: Path):
    src = tmp_path / "shade.rdsl"
    src.write_text(HOST_SRC)
    assert_user_error(rdsl_cli("compile", str(src), "--target", "c", "--width", "3"),
                      "unsupported SIMD width 3", "1, 4, 8, 16")
    assert_user_error(rdsl_cli("compile", str(src), "--target", "avx2", "--width", "4"),
                      "target `avx2` has SIMD width 8")
    assert_user_error(rdsl_cli("compile", str(src), "--target", "c", "--emit", "asm"),
                      "needs an LLVM target")
    with pytest.raises(CompileError, match="valid widths"):
        rdsl.jit(HOST_SRC, target="c", width=32)


def test_missing_cc(tmp_path: Path, monkeypatch):
    build = Build.of("c", "rgb", width=4)
    module, _ = compile_kernels(HOST_SRC, build)
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, gcc or clang there
    with pytest.raises(CompileError, match=r"no C compiler \(`cc`\)"):
        build_c_library(module, build.target, tmp_path, "shade")
    # the source alone needs no compiler
    paths = build_c_library(module, build.target, tmp_path, "shade", source_only=True)
    assert paths["c"].is_file() and paths["header"].is_file()


def test_trace_is_a_clear_error(tmp_path: Path):
    src = tmp_path / "rays.rdsl"
    src.write_text("fn blocked(o: Vec3, d: Vec3) -> Bool {\n"
                   "    return occluded(Ray { o: o, d: d, tmax: 1.0 });\n}\n")
    r = rdsl_cli("compile", str(src), "--target", "c", "--emit", "c", "-o",
                 str(tmp_path / "rays"))
    assert_user_error(r, "rays.rdsl:2:", "`occluded`", "cannot trace rays")
