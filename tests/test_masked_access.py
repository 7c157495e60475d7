"""Masked loads and stores whose active lanes' indices are consecutive while the inactive
lanes' are not (a packet's finished lanes keep stale indices): the LLVM backend takes one
vector access for them (compiler/backends/llvm_ops.py, ``_consecutive``).  The values read
must be those of a lane-by-lane run, and no element an inactive lane names may be written."""

from __future__ import annotations

import numpy as np
import pytest
import rdsl
from rdsl.compiler.targets import TARGETS, host_supports

SRC = """
fn read(j: Int, A: [Float]) -> Float {
    let active = j % 5 != 2;
    let i = select(active, j, 4000 - 7 * j);   // stale, scattered indices where inactive
    var out = -1.0;
    if active { out = A[i]; }
    return out;
}
fn write(j: Int, B: [Float]) {
    let active = j % 5 != 2;
    let i = select(active, j, 4000 - 7 * j);
    if active { B[i] = Float(j) + 0.5; }
}
fn write_all_off(j: Int, B: [Float]) {
    let i = 3 * j;
    if j < 0 { B[i] = 1.0; }
}
"""
N = 203  # not a multiple of any width: a masked tail too
VECTOR = [t for t in ("sse4", "avx2", "avx512") if host_supports(TARGETS[t])]


@pytest.mark.parametrize("target", ["scalar", *VECTOR])
def test_masked_accesses_with_stale_inactive_lanes(target):
    mod = rdsl.jit(SRC, target=target)
    j = np.arange(N, dtype=np.int32)
    active = j % 5 != 2
    A = np.random.default_rng(1).random(4096).astype(np.float32)
    got = np.asarray(mod.read(j, A))
    np.testing.assert_array_equal(got, np.where(active, A[np.minimum(j, 4095)], -1.0))
    B = np.full(4096, -7.0, np.float32)
    mod.write(j, B)
    want = np.full(4096, -7.0, np.float32)
    want[j[active]] = j[active] + 0.5
    np.testing.assert_array_equal(B, want)  # nothing an inactive lane names is written
    C = np.full(4096, -7.0, np.float32)
    mod.write_all_off(j, C)  # no lane active at all
    assert np.all(C == -7.0)
