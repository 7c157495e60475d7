"""The SIMD C backend against LLVM: the GGX kernel (bench/ggx_kernel.rdsl) over N samples,
one thread, component arrays with the output reused (the call that measures the kernel
and not the copies), on the c target at widths 4, 8 and 16 (``cc -O2 -march=native``)
and the sse4, avx2 and avx512 LLVM targets this CPU runs.  Prints time, Msamples/s, the
ratio to the LLVM target of the same width, and whether the outputs agree bit for bit.
Not a test: run it by hand.

    python bench/c_backend.py [--n 4194304] [--repeat 5] [--march native]

``--march`` is what the c builds are compiled for (``-march=...``; the LLVM targets have
their own: sse4 is x86-64 plus SSE4.2, avx2 Haswell, avx512 Skylake-AVX512), e.g.
``--march haswell`` to give c8 the instruction set of avx2.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rdsl
from rdsl.compiler.backends.c_build import CFLAGS, build_c_library, compile_shared
from rdsl.compiler.build import Build
from rdsl.compiler.driver import compile_kernels
from rdsl.compiler.targets import get_target, host_supports

sys.path.insert(0, str(Path(__file__).parent))
from vector_speedup import KERNEL, inputs

LLVM_BY_WIDTH = {4: "sse4", 8: "avx2", 16: "avx512"}


def build_c(width: int, march: str, out: Path) -> rdsl.Module:
    """The kernel on target c at ``width``, compiled by cc with ``-march=MARCH``."""
    build = Build.of("c", "rgb", width)
    module, _ = compile_kernels(KERNEL, build)
    stem = f"ggx_c{width}"
    paths = build_c_library(module, build.target, out, stem, source_only=True)
    flags = tuple(f"-march={march}" if f.startswith("-march=") else f for f in CFLAGS)
    compile_shared(paths["c"], out / f"{stem}.so", flags)
    return rdsl.load(out / f"{stem}.so")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4 * 1024 * 1024)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--march", default="native")
    args = ap.parse_args()
    wi, u1, u2, alpha = inputs(args.n)
    comp = (np.asfortranarray(wi), u1, np.asfortranarray(u2), alpha)
    kernels, compile_s = {}, {}
    with tempfile.TemporaryDirectory() as cache:
        os.environ["RDSL_CACHE_DIR"] = cache
        for width, llvm in LLVM_BY_WIDTH.items():
            builds = [(f"c{width}", "c")]
            if host_supports(get_target(llvm)):
                builds.append((llvm, llvm))
            for label, target in builds:
                t = time.perf_counter()
                mod = build_c(width, args.march, Path(cache)) if target == "c" else \
                    rdsl.jit(KERNEL, target=target)
                kernels[label] = mod["ggx_eval_sample"]
                compile_s[label] = time.perf_counter() - t
    outs = {label: k(*comp, threads=1) for label, k in kernels.items()}
    times: dict[str, list[float]] = {label: [] for label in kernels}
    for _ in range(args.repeat):  # interleaved, so machine noise hits every build alike
        for label, k in kernels.items():
            t = time.perf_counter()
            k(*comp, threads=1, out=outs[label])
            times[label].append(time.perf_counter() - t)
    med = {label: statistics.median(v) for label, v in times.items()}
    print(f"\nGGX sample+eval, {args.n} samples, one thread, component arrays, median of "
          f"{args.repeat}; c built with -march={args.march}\n")
    print(f"{'build':8} {'s':>8} {'Msamp/s':>8} {'vs LLVM':>8} {'bitwise':>8} "
          f"{'compile s':>10}")
    for width, llvm in LLVM_BY_WIDTH.items():
        for label in (f"c{width}", llvm):
            if label not in kernels:
                continue
            s = med[label]
            ratio = same = ""
            if label.startswith("c") and llvm in kernels:
                ratio = f"{med[llvm] / s:7.2f}x"
                same = "yes" if np.array_equal(outs[label], outs[llvm], equal_nan=True) \
                    else "NO"
            print(f"{label:8} {s:8.4f} {args.n / s / 1e6:8.1f} {ratio:>8} {same:>8} "
                  f"{compile_s[label]:10.2f}")
    print("\n'vs LLVM': the c build's speed over the LLVM target of the same width "
          "(above 1 = c is faster)")


if __name__ == "__main__":
    main()
