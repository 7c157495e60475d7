"""AD kernels on every target: the forward-mode and reverse-mode builds of one program
(a loop with a data-dependent trip count, nested ifs, parameter reads, sin and detach) give
on the C, OpenCL (PoCL) and SPIR-V (lavapipe) targets bit for bit the values, tangents and
gradients of the LLVM build, as the plain kernels do (tests/test_c_backend.py and the
others).  PTX is compiled and checked by ptxas only (no GPU here)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import rdsl
from rdsl.compiler.targets import get_target, host_supports
from test_ad_reverse import LOOP, NPRM

REF = "avx2" if host_supports(get_target("avx2")) else "scalar"


def _unavailable(target: str) -> str | None:
    """Why ``target`` cannot run here (None when it can)."""
    if target == "c":
        return None if shutil.which("cc") else "no C compiler (cc)"
    if target == "opencl":
        from rdsl.runtime.opencl import OpenCLUnavailable, opencl_context

        try:
            opencl_context()
        except OpenCLUnavailable as e:
            return str(e)
        return None
    for tool, pkg in (("glslangValidator", "glslang-tools"), ("spirv-val", "spirv-tools")):
        if shutil.which(tool) is None:
            return f"missing {tool} (Debian's {pkg})"
    try:
        from rdsl.runtime.vulkan import Device

        Device.get()
    except Exception as e:  # noqa: BLE001 - VulkanUnavailable, or any error of a driver
        return f"no Vulkan: {e}"
    return None


TARGETS = [pytest.param(t, marks=pytest.mark.skipif(_unavailable(t) is not None,
                                                    reason=str(_unavailable(t))))
           for t in ("c", "opencl", "spirv")]


def _inputs():
    x = np.linspace(-0.5, 2.0, 37).astype(np.float32)
    prm = np.array([0.7, 1.3, 0.8, 2.0, 0.9], np.float32)
    a = np.random.default_rng(0).standard_normal(x.size).astype(np.float32)
    return x, prm, a


def _forward(target: str) -> list[np.ndarray]:
    fwd = rdsl.jit(LOOP, build=rdsl.Build.of(target, "rgb", ad="forward"))
    x, prm, _ = _inputs()
    out = []
    for t in np.eye(NPRM, dtype=np.float32):
        out += [np.asarray(v) for v in fwd.k(x, prm, t, np.ones_like(x))]
    return out


def _reverse(target: str) -> list[np.ndarray]:
    rev = rdsl.jit(LOOP, build=rdsl.Build.of(target, "rgb", ad="reverse"))
    x, prm, a = _inputs()
    grad = np.zeros(x.size * NPRM, np.float32)
    value, gx = rev.k(x, prm, a, grad, np.arange(x.size, dtype=np.int32) * NPRM)
    return [np.asarray(value), np.asarray(gx), grad]


@pytest.mark.parametrize("target", TARGETS)
@pytest.mark.parametrize("mode", ["forward", "reverse"])
def test_ad_kernels_match_the_llvm_build_bit_for_bit(target: str, mode: str) -> None:
    run = _forward if mode == "forward" else _reverse
    want, got = run(REF), run(target)
    assert any(np.any(g != 0) for g in want[1:])  # derivatives that are there to compare
    for w, g in zip(want, got):
        np.testing.assert_array_equal(g.view(np.uint32), w.view(np.uint32))


@pytest.mark.parametrize("mode", ["forward", "reverse"])
def test_ad_kernels_pass_ptxas(mode: str) -> None:
    from rdsl.compiler.backends.ptx import emit_ptx, find_ptxas, run_ptxas
    from rdsl.compiler.driver import compile_kernels
    from rdsl.compiler.targets import ptx_target

    ptxas = find_ptxas("sm_80")
    if ptxas is None:
        pytest.skip("no ptxas (CUDA toolkit, or pip's nvidia-cuda-nvcc-cu12)")
    build = rdsl.Build(ptx_target("sm_80"), rdsl.Build.of("scalar", "rgb").model, mode)
    module, _ = compile_kernels(LOOP, build)
    run_ptxas(emit_ptx(module, build.target), "sm_80", ptxas)
