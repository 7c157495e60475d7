"""Quickstart: compile the stdlib rough conductor for this CPU and use it from numpy.

    python examples/quickstart.py

It compiles `stdlib/bsdf/roughconductor.rdsl` (GGX, copper-like eta/k) for the best SIMD
target of this machine, samples 1M directions, checks that `sample`'s weight equals
`eval / pdf`, estimates the directional albedo at a few incident angles, and prints the
timings (the second run of this script loads the kernels from the disk cache).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import rdsl

ROOT = Path(__file__).resolve().parent.parent
N = 1 << 20


def surface(n: int, theta: float) -> dict:
    wi = np.tile(np.array([np.sin(theta), 0.0, np.cos(theta)], np.float32), (n, 1))
    zeros = np.zeros((n, 3), np.float32)
    return {"p": zeros, "n": zeros + [0, 0, 1], "sh_n": zeros + [0, 0, 1],
            "uv": np.zeros((n, 2), np.float32), "wi": wi, "t": np.ones(n, np.float32),
            "valid": np.ones(n, bool)}


def main() -> None:
    t = time.perf_counter()
    mod = rdsl.jit(ROOT / "stdlib" / "bsdf" / "roughconductor.rdsl", target="host")
    how = "loaded from cache" if mod.from_cache else "compiled"
    print(f"roughconductor: {how} for target `{mod.target}` in {time.perf_counter() - t:.2f} s")
    rng = np.random.default_rng(0)
    params = {"alpha": 0.2, "eta": (0.2, 0.92, 1.1), "k": (3.9, 2.45, 2.14)}
    print(f"\n{'theta_i':>8} {'albedo R':>9} {'G':>7} {'B':>7} {'max|w - f/p|':>13} "
          f"{'Msamples/s':>11}")
    for deg in (0, 30, 60, 80):
        si = surface(N, np.radians(deg))
        u1 = rng.random(N, dtype=np.float32)
        u2 = rng.random((N, 2), dtype=np.float32)
        t = time.perf_counter()
        s = mod["roughconductor.sample"](si, u1, u2, **params)
        dt = time.perf_counter() - t
        ok = s["pdf"] > 0
        f = mod["roughconductor.eval"](si, s["wo"], **params)
        p = mod["roughconductor.pdf"](si, s["wo"], **params)
        ratio = np.where(ok[:, None], f / np.maximum(p, 1e-30)[:, None], 0)
        err = float(np.max(np.abs(ratio[ok] - s["weight"][ok]) /
                           np.maximum(np.abs(s["weight"][ok]), 1e-3)))
        albedo = s["weight"].mean(axis=0)
        print(f"{deg:8d} {albedo[0]:9.4f} {albedo[1]:7.4f} {albedo[2]:7.4f} {err:13.2e} "
              f"{N / dt / 1e6:11.1f}")


if __name__ == "__main__":
    main()
