"""Throughput of the stdlib math functions: ns per call, vectorized kernels over 2^20 floats.

    python bench/math_speed.py                          # host target, every function
    python bench/math_speed.py --targets avx2,scalar --functions tan,rsqrt

Each kernel ``k_NAME(x) = NAME(x)`` runs over 2^20 float32 inputs drawn on the function's
documented domain (``runtime/testkit/ulp.py``); the best of ``--repeat`` runs is kept, so
the numbers are the kernel's, not the machine's load. Compare two branches by ratio.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import rdsl
from rdsl.runtime.testkit.ulp import UNARY, wrappers


def inputs(fn, n: int, rng) -> np.ndarray:
    lo, hi = max(fn.lo, -20.0), min(fn.hi, 20.0)
    return rng.uniform(lo, hi, n).astype(np.float32)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--targets", default="host")
    ap.add_argument("--functions", default=",".join(u.name for u in UNARY))
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--n", type=int, default=1 << 20)
    args = ap.parse_args(argv)
    chosen = [u for u in UNARY if u.name in args.functions.split(",")]
    src = wrappers([u.name for u in chosen])
    rng = np.random.default_rng(7)
    print("| function | target | ns per call |")
    print("|---|---|---|")
    for target in args.targets.split(","):
        mod = rdsl.jit(src, target=target)
        for fn in chosen:
            x = inputs(fn, args.n, rng)
            k = mod[f"k_{fn.name}"]
            k(x)
            best = min(_timed(k, x) for _ in range(args.repeat))
            print(f"| {fn.name} | {target} | {best / args.n * 1e9:.3f} |", flush=True)
    return 0


def _timed(k, x) -> float:
    t0 = time.perf_counter()
    k(x)
    return time.perf_counter() - t0


if __name__ == "__main__":
    sys.exit(main())
