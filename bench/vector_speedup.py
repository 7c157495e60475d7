"""Vector speedup: a shading-heavy kernel (GGX visible-normal sampling plus evaluation) over
4M samples on every CPU target, single-threaded and on all cores.

Prints a table of time, Msamples/s and speedup over `scalar`, then cold compile time and
cached load time (in a fresh process).  Not a test: run it by hand.

    python bench/vector_speedup.py [--n 4194304] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rdsl
from rdsl.compiler.targets import get_target, host_supports

KERNEL = Path(__file__).parent / "ggx_kernel.rdsl"
TARGETS = ["scalar", "sse4", "avx2", "avx512"]


def inputs(n: int) -> tuple:
    rng = np.random.default_rng(1)
    wi = rng.standard_normal((n, 3)).astype(np.float32)
    wi[:, 2] = np.abs(wi[:, 2]) + 0.05
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    u1 = rng.random(n, dtype=np.float32)
    u2 = rng.random((n, 2), dtype=np.float32)
    alpha = np.full(n, 0.3, np.float32)
    return wi, u1, u2, alpha


def timed(fn, repeat: int) -> float:
    fn()  # warm up (page faults, thread pool)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def cached_load_seconds(target: str, cache: str) -> float:
    # numpy and the runtime are imported before the clock starts: every caller of a kernel
    # has numpy loaded already; what is timed is the cache lookup, dlopen and manifest
    code = ("import time, numpy, rdsl, rdsl.runtime.api; t = time.perf_counter(); "
            f"m = rdsl.jit({str(KERNEL)!r}, target={target!r}); "
            "assert m.from_cache; print(time.perf_counter() - t)")
    env = dict(os.environ, RDSL_CACHE_DIR=cache)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True)
    return float(out.stdout.strip())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4 * 1024 * 1024)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    data = inputs(args.n)
    cores = os.cpu_count() or 1
    kernels = {}
    compile_s = {}
    with tempfile.TemporaryDirectory() as cache:
        os.environ["RDSL_CACHE_DIR"] = cache
        for name in TARGETS:
            if not host_supports(get_target(name)):
                print(f"{name}: not supported by this CPU, skipped")
                continue
            t = time.perf_counter()
            kernels[name] = rdsl.jit(KERNEL, target=name)["ggx_eval_sample"]
            compile_s[name] = time.perf_counter() - t
        cached = {name: cached_load_seconds(name, cache) for name in kernels}
    reference = kernels["scalar"](*data, threads=1)
    mismatch = {}
    for name, k in kernels.items():
        out = k(*data, threads=1)
        mismatch[name] = float(np.mean(~np.isclose(out, reference, rtol=1e-5, atol=1e-6)))
    # interleave the targets across repeats so machine noise hits them alike
    one: dict[str, list[float]] = {n: [] for n in kernels}
    alln: dict[str, list[float]] = {n: [] for n in kernels}
    for _ in range(args.repeat):
        for name, k in kernels.items():
            one[name].append(timed(lambda: k(*data, threads=1), 1))
            alln[name].append(timed(lambda: k(*data, threads=cores), 1))
    rows = [(n, statistics.median(one[n]), statistics.median(alln[n]), compile_s[n],
             cached[n], mismatch[n]) for n in kernels]
    base1 = rows[0][1]
    print(f"\nGGX sample+eval, {args.n} samples, median of {args.repeat} runs, "
          f"{cores} cores\n")
    print(f"{'target':8} {'1 thread s':>11} {'Msamp/s':>8} {'speedup':>8} "
          f"{'all cores s':>12} {'speedup':>8} {'compile s':>10} {'cached s':>9} "
          f"{'!=scalar':>9}")
    for name, t1, tn, cold, cached, mism in rows:
        print(f"{name:8} {t1:11.4f} {args.n / t1 / 1e6:8.1f} {base1 / t1:7.2f}x "
              f"{tn:12.4f} {base1 / tn:7.2f}x {cold:10.2f} {cached:9.3f} {mism:9.2%}")
    print("\nspeedup is over `scalar` on 1 thread; '!=scalar' is the fraction of outputs "
          "that differ from scalar beyond 1e-5 relative")


if __name__ == "__main__":
    main()
