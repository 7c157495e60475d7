"""Gathers at offsets of one index share one run-time check of whether the lanes' indices
are consecutive (compiler/backends/llvm_runs.py): the values read are those of a
lane-by-lane run, for indices that are consecutive, scattered, or consecutive in some
packets only, and the lowered kernel checks each index once per mask, not once per load."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.compiler.backends.llvm import lower_module
from rdsl.compiler.build import Build
from rdsl.compiler.driver import compile_kernels
from rdsl.compiler.targets import TARGETS, host_supports

SRC = """
fn taps(j: Int, S: [Float], N: [Int]) -> Float {
    let n = N[0];   // uniform: the offsets are uniform, the index varies by lane
    var acc = -1.0;
    if j % 5 != 2 {
        acc = S[j] + 2.0 * S[j + n] + 4.0 * S[2 * n + j] + 8.0 * S[j - 1 + n];
    }
    return acc;
}
"""
N = 203  # not a multiple of any width: a masked tail too
VECTOR = [t for t in ("sse4", "avx2", "avx512") if host_supports(TARGETS[t])]


def _want(j: np.ndarray, S: np.ndarray, n: int) -> np.ndarray:
    acc = S[j] + np.float32(2) * S[j + n] + np.float32(4) * S[2 * n + j] \
        + np.float32(8) * S[j - 1 + n]
    return np.where(j % 5 != 2, acc, np.float32(-1)).astype(np.float32)


@pytest.mark.parametrize("target", ["scalar", *VECTOR])
@pytest.mark.parametrize("order", ["consecutive", "scattered", "mixed"])
def test_gathers_at_offsets_of_one_index(target, order):
    mod = rdsl.jit(SRC, target=target)
    n = 300
    S = np.random.default_rng(2).random(3 * n + N + 1).astype(np.float32)
    j = np.arange(1, N + 1, dtype=np.int32)
    if order == "scattered":
        j = np.random.default_rng(3).permutation(j)
    elif order == "mixed":  # a few packets out of order, the rest in order
        j[40:56] = j[40:56][::-1].copy()
    got = np.asarray(mod.taps(j, S, np.array([n], np.int32)))
    np.testing.assert_array_equal(got, _want(j, S, n))


@pytest.mark.parametrize("target", ["avx2", "avx512"])
def test_one_check_per_index_and_mask(target):
    module, _ = compile_kernels(SRC, Build.of(target))
    llvm = str(lower_module(module, target))
    body = llvm[llvm.index("define internal"):]
    body = body[:body.index("\n}\n")]
    calls = [line for line in body.splitlines() if " call " in line]
    # four loads at offsets of j under one mask: one check (before: one per load)
    assert sum("llvm.cttz" in c for c in calls) == 1
    assert sum("llvm.masked.load" in c for c in calls) == 4
    assert sum("llvm.masked.gather" in c for c in calls) == 4
