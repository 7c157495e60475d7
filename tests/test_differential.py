"""Differential tests: every corpus kernel on every target against the IR interpreter.

The interpreter runs the scalarized IR one lane at a time with exact f32 semantics; the
compiled kernels run vectorized (masks, gathers, scatters) on scalar, SSE4, AVX2 and
AVX-512.  No transcendental is involved (they are written in rdsl, so they are IR too), so
results must agree bit for bit.  Inputs come from hypothesis.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rdsl
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.interp import run_function
from rdsl.compiler.targets import get_target, host_supports

CORPUS = Path(__file__).parent / "corpus"
TARGETS = ["scalar", "sse4", "avx2", "avx512"]
DTYPES = {"f32": np.float32, "i32": np.int32, "u32": np.uint32, "u64": np.uint64,
          "bool": np.bool_}

f32_any = st.floats(width=32, allow_nan=True, allow_infinity=True)
f32_small = st.floats(-1000, 1000, width=32)
i32_any = st.integers(-2**31, 2**31 - 1)
i32_small = st.integers(-100000, 100000)
u32_any = st.integers(0, 2**32 - 1)

# per kernel: strategies of the scalar leaves of each (non-buffer) parameter
CASES = {
    ("math", "poly"): [f32_any, f32_any],
    ("math", "vecs"): [f32_small] * 7,
    ("math", "ints"): [i32_any, i32_any],
    ("math", "uints"): [u32_any, u32_any],
    ("math", "casts"): [f32_any, i32_any],
    ("math", "compare"): [f32_any, f32_any],
    ("control", "branchy"): [f32_any, f32_any],
    ("control", "collatz"): [i32_small],
    ("control", "sum_to"): [i32_small, f32_small],
    ("control", "early"): [f32_small],
    ("control", "nested"): [i32_small, i32_small],
    ("control", "halve_until"): [f32_any],
    ("memory", "gather"): [i32_small],
    ("memory", "scatter"): [i32_small, f32_small],
    ("memory", "histogram"): [f32_any],
}


def _buffers(fn_name: str) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    return {
        "gather": [rng.standard_normal(64).astype(np.float32)],
        "scatter": [np.zeros(128, np.float32)],
        "histogram": [rng.integers(-50, 50, 16).astype(np.int32)],
    }.get(fn_name, [])


@pytest.fixture(scope="module")
def interp_modules():
    mods = {}
    for f in CORPUS.glob("*.rdsl"):
        m = frontend(f)
        run_passes(m, pipeline(Build.of("scalar", "rgb")), stop_after="scalarize")
        mods[f.stem] = m
    return mods


@pytest.fixture(scope="module")
def compiled():
    out = {}
    for t in TARGETS:
        if not host_supports(get_target(t)):
            continue
        for f in CORPUS.glob("*.rdsl"):
            out[(f.stem, t)] = rdsl.jit(f, target=t)
    return out


def _rows(strategies):
    return st.lists(st.tuples(*strategies), min_size=1, max_size=41)


def _bits(a: np.ndarray) -> np.ndarray:
    """Bit patterns, with every NaN made canonical (NaN sign and payload are not specified:
    x86 gives 0/0 a negative NaN, LLVM's constant folder a positive one)."""
    a = np.asarray(a)
    if a.dtype != np.float32:
        return a
    return np.where(np.isnan(a), np.float32(np.nan), a).view(np.uint32)


@pytest.mark.xdist_group("corpus-llvm")  # one worker: the module fixtures build once
@pytest.mark.parametrize("case", sorted(CASES), ids=lambda c: f"{c[0]}.{c[1]}")
def test_matches_interpreter(case, interp_modules, compiled):
    check_case(case, interp_modules[case[0]], compiled)


def check_case(case: tuple[str, str], module, compiled: dict) -> None:
    """Hypothesis rows of ``case`` (file, kernel) through the interpreter on ``module`` and
    through every ``compiled[(file, label)]`` kernel module: bitwise equal results and
    buffers (NaNs canonical)."""
    file, fn_name = case
    fn = module.functions[fn_name]
    leaf_params = [p for p in fn.params if not p.uniform]
    dtypes = [DTYPES[p.value.type.name] for p in leaf_params]
    abi = fn.attrs["abi_params"]

    @settings(max_examples=12, deadline=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
    @given(_rows(CASES[case]))
    def check(rows):
        n = len(rows)
        cols = [np.array([r[i] for r in rows], dtype=dt) for i, dt in enumerate(dtypes)]
        # reference: the interpreter, one lane at a time, buffers mutated in order
        ref_bufs = _buffers(fn_name)
        expected = []
        for k in range(n):
            args, it, bi = [], iter(cols), iter(ref_bufs)
            for p in fn.params:
                args.append(next(bi) if p.uniform else next(it)[k])
            expected.append(run_function(module, fn_name, args))
        for (f, target), kmod in compiled.items():
            if f != file:
                continue
            bufs = _buffers(fn_name)
            # regroup leaf columns into source-level arguments
            call_args, it, bi = [], iter(cols), iter(bufs)
            for prm in abi:
                if prm["type"]["kind"] == "buffer":
                    call_args.append(next(bi))
                elif len(prm["leaves"]) == 1:
                    call_args.append(next(it))
                else:
                    call_args.append(np.stack([next(it) for _ in prm["leaves"]], axis=1))
            got = kmod[fn_name](*call_args, threads=1)
            if got is not None:
                got = np.asarray(got).reshape(n, -1)
                want = np.array([[np.asarray(v).astype(got.dtype) for v in e]
                                 for e in expected]).reshape(n, -1)
                assert np.array_equal(_bits(got), _bits(want)), \
                    f"{target}: {fn_name}{rows} -> {got.tolist()} != {want.tolist()}"
            for b, rb in zip(bufs, ref_bufs):
                assert np.array_equal(_bits(b), _bits(rb)), f"{target}: buffer differs"

    check()
