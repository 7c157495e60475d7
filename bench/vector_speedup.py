"""Vector speedup: a shading-heavy kernel (GGX visible-normal sampling plus evaluation) over
4M samples on every CPU target, single-threaded and on all cores.

Each target is called three ways: the natural call (C-order ``(N, 3)`` and ``(N, 2)`` arrays,
a fresh result every call), the component-array call (every vector component its own
contiguous array, the output reused with ``out=``) and the natural call into a C-order
``(N, 4)`` ``out=`` ("C out").  Prints time, Msamples/s and speedup
over `scalar` for both, the natural call on all cores, then what a fresh output costs
without the kernel's output pool, cold compile time and cached load time (in a fresh
process).  Not a test: run it by hand.

    python bench/vector_speedup.py [--n 4194304] [--repeat 5] [--clock wall|cpu]

``--clock cpu`` times the one-thread calls in CPU time of the calling thread, which other
processes on a loaded machine disturb less than wall time.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

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


def clock(kind: str) -> Any:
    return time.thread_time if kind == "cpu" else time.perf_counter


def timed(fn: Any, clk: Any = time.perf_counter) -> float:
    t = clk()
    fn()
    return clk() - t


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
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall")
    args = ap.parse_args()
    wi, u1, u2, alpha = inputs(args.n)
    # the component arrays: every vector component contiguous (Fortran order)
    comp = (np.asfortranarray(wi), u1, np.asfortranarray(u2), alpha)
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
    reference = kernels["scalar"](wi, u1, u2, alpha, threads=1)
    mismatch, outs = {}, {}
    for name, k in kernels.items():
        outs[name] = k(*comp, threads=1)
        assert np.array_equal(k(wi, u1, u2, alpha, threads=1), outs[name], equal_nan=True)
        mismatch[name] = float(np.mean(~np.isclose(outs[name], reference, rtol=1e-5,
                                                   atol=1e-6)))
    clk = clock(args.clock)
    calls = {}
    c_out = np.empty((args.n, 4), np.float32)  # a C-order out= (every target writes it)
    for name, k in kernels.items():
        calls[name] = {
            "natural": lambda k=k: k(wi, u1, u2, alpha, threads=1),
            "component": lambda k=k, o=outs[name]: k(*comp, threads=1, out=o),
            "C out": lambda k=k, o=c_out: k(wi, u1, u2, alpha, threads=1, out=o),
            "all cores": lambda k=k: k(wi, u1, u2, alpha, threads=cores)}
        for fn in calls[name].values():
            fn()  # warm up (page faults, thread pool, the output pool)
    # interleave the targets and calls across repeats so machine noise hits them alike
    times = {(n, c): [] for n in calls for c in calls[n]}
    for _ in range(args.repeat):
        for name, by_call in calls.items():
            for call, fn in by_call.items():
                times[name, call].append(timed(fn, time.perf_counter if call == "all cores"
                                               else clk))
    med = {key: statistics.median(v) for key, v in times.items()}
    report(args, cores, kernels, med)
    fresh_output_cost(kernels, (wi, u1, u2, alpha), args.repeat, clk)
    print(f"\n{'target':8} {'compile s':>10} {'cached s':>9} {'!=scalar':>9}")
    for name in kernels:
        print(f"{name:8} {compile_s[name]:10.2f} {cached[name]:9.3f} {mismatch[name]:9.2%}")
    print("\n'!=scalar' is the fraction of outputs that differ from scalar beyond 1e-5 relative")


def report(args: Any, cores: int, kernels: dict[str, Any], med: dict[tuple, float]) -> None:
    n = args.n
    print(f"\nGGX sample+eval, {n} samples, median of {args.repeat} runs "
          f"({args.clock} clock on one thread), {cores} cores; speedups over `scalar` on "
          "one thread, called the same way\n")
    print(f"{'target':8} {'natural s':>10} {'Msamp/s':>8} {'speedup':>8} "
          f"{'component s':>12} {'Msamp/s':>8} {'speedup':>8} {'nat/comp':>9} "
          f"{'all cores s':>12} {'speedup':>8} {'C out/comp':>11}")
    nat0, comp0 = med["scalar", "natural"], med["scalar", "component"]
    for name in kernels:
        nat, comp, alln = (med[name, c] for c in ("natural", "component", "all cores"))
        print(f"{name:8} {nat:10.4f} {n / nat / 1e6:8.1f} {nat0 / nat:7.2f}x "
              f"{comp:12.4f} {n / comp / 1e6:8.1f} {comp0 / comp:7.2f}x {nat / comp:9.3f} "
              f"{alln:12.4f} {nat0 / alln:7.2f}x {med[name, 'C out'] / comp:11.3f}")
    print("\nnatural: C-order (N, 3)/(N, 2) arrays, a fresh result each call; component: "
          "one contiguous array per component, out= reused; C out: the natural call into a "
          "reused C-order (N, 4) out=")


def fresh_output_cost(kernels: dict[str, Any], data: tuple, repeat: int, clk: Any) -> None:
    """The natural call with the output pool on and off (a fresh block every call), on the
    fastest target: what page faulting in a fresh output costs."""
    name = list(kernels)[-1]
    k = kernels[name]
    capacity = k.pool.capacity
    on, off, faults = [], [], []
    for _ in range(repeat):
        k.pool.capacity = capacity
        on.append(timed(lambda: k(*data, threads=1), clk))
        k.pool.capacity = 0
        f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        off.append(timed(lambda: k(*data, threads=1), clk))
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
    k.pool.capacity = capacity
    mb = len(data[1]) * 16 / 2 ** 20
    print(f"\nfresh {mb:.0f} MB output on every {name} call (output pool off): "
          f"{statistics.median(off):.4f} s vs {statistics.median(on):.4f} s with the pool "
          f"(+{statistics.median(off) - statistics.median(on):.4f} s, "
          f"{statistics.median(faults):.0f} page faults)")


if __name__ == "__main__":
    main()
