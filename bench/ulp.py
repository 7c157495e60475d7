"""Math to the ulp: each stdlib function against its float64 truth, per target.

    python bench/ulp.py                       # sampled: 2^22 patterns per function
    python bench/ulp.py --exhaustive          # every one of the 2^32 float32 inputs
    python bench/ulp.py --targets scalar,avx2 --functions sin,tan

For each function of ``runtime/testkit/ulp.py``'s table and each target, the kernel
``k_NAME(x) = NAME(x)`` is compiled and run over float32 bit patterns (all of them with
``--exhaustive``, in chunks; else a uniform sample of patterns, which covers every exponent
evenly, plus the special values). The table gives max and mean ulp on the documented domain
(the bound ``stdlib/math.rdsl`` states), the input where the max was seen, and the count of
mismatched special values (NaN/inf/signed zero) over all inputs. It exits 1 if a max exceeds
its documented bound. Two cores do the exhaustive sweep of one function on one target in
about a minute (the float64 truth costs as much as the kernel).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import rdsl  # noqa: E402
from rdsl.runtime.testkit.ulp import UNARY, float32_chunk, ulp_error, wrappers  # noqa: E402

CHUNK = 1 << 24


def sweep(kernel, fn, patterns) -> dict:
    """Max/mean error on the domain, worst input, special-value mismatches."""
    worst, worst_x, total, n, bad_special = 0.0, 0.0, 0.0, 0, 0
    for x in patterns:
        got = kernel(x)
        with np.errstate(all="ignore"):
            ref = fn.truth(x.astype(np.float64))
        inside = np.flatnonzero((x >= fn.lo) & (x <= fn.hi))
        if inside.size:
            e = ulp_error(got[inside], ref[inside])
            k = int(np.argmax(e))
            if e[k] > worst:
                worst, worst_x = float(e[k]), float(x[inside[k]])
            total += float(e[np.isfinite(e)].sum())
            n += int(e.size)
        # NaN, infinities and zeros must come out exactly (0 ulp): NaN for NaN, else equal
        special = ~np.isfinite(ref) | (ref == 0)
        g, r = got[special], ref[special]
        bad_special += int(np.count_nonzero(~((np.isnan(g) & np.isnan(r)) | (g == r))))
    return {"max": worst, "mean": total / max(n, 1), "at": worst_x, "n": n,
            "special": bad_special}


def patterns(exhaustive: bool, samples: int, seed: int):
    if exhaustive:
        for start in range(0, 1 << 32, CHUNK):
            yield float32_chunk(start, CHUNK)
        return
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 1 << 32, samples, dtype=np.uint64).astype(np.uint32)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 0.5, 1e-45, 3.4e38],
                       np.float32)
    yield np.concatenate([bits.view(np.float32), special])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--targets", default="scalar,host")
    ap.add_argument("--functions", default=",".join(u.name for u in UNARY))
    ap.add_argument("--exhaustive", action="store_true", help="all 2^32 inputs")
    ap.add_argument("--samples", type=int, default=1 << 22)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    chosen = [u for u in UNARY if u.name in args.functions.split(",")]
    unknown = set(args.functions.split(",")) - {u.name for u in chosen}
    if unknown:
        ap.error(f"unknown function(s): {', '.join(sorted(unknown))}")
    src = wrappers([u.name for u in chosen])
    mode = "all 2^32 inputs" if args.exhaustive else f"{args.samples} sampled bit patterns"
    print(f"ulp errors against float64, {mode}\n")
    print(f"| function | target | domain | max ulp | mean ulp | worst input | bound | "
          f"special mismatches | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    failed = False
    for target in args.targets.split(","):
        mod = rdsl.jit(src, target=target)
        for fn in chosen:
            t0 = time.perf_counter()
            r = sweep(mod[f"k_{fn.name}"], fn, patterns(args.exhaustive, args.samples,
                                                          args.seed))
            dt = time.perf_counter() - t0
            over = r["max"] > fn.bound or r["special"] > 0
            failed |= over
            print(f"| {fn.name} | {target} | [{fn.lo:.3g}, {fn.hi:.3g}] | {r['max']:.3f} | "
                  f"{r['mean']:.4f} | {r['at']!r} | {fn.bound} | {r['special']} | "
                  f"{dt:.1f} |{'  <-- over' if over else ''}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
