"""Math to the ulp: each stdlib function against its float64 truth, per target.

    python bench/ulp.py                       # sampled: 2^22 patterns per function
    python bench/ulp.py --exhaustive          # every one of the 2^32 float32 inputs
    python bench/ulp.py --targets scalar,avx2 --functions sin,tan
    python bench/ulp.py --exhaustive --functions asin --bits 0:80000000   # x >= +0 only

For each function of ``runtime/testkit/ulp.py``'s table and each target, the kernel
``k_NAME(x) = NAME(x)`` is compiled and run over float32 bit patterns (all of them with
``--exhaustive``, in chunks; else a uniform sample of patterns, which covers every exponent
evenly, plus the special values). The table gives max and mean ulp on the documented domain
(the bound ``stdlib/math.rdsl`` states), the input where the max was seen, and the count of
mismatched special values (NaN/inf/signed zero) over all inputs. It exits 1 if a max exceeds
its documented bound. The truth and the statistics run in C (``ulp_stats.c``, built with cc on
first use; libm's float64 functions, erfinv by Newton steps on libm's erf and erfc) unless cc is missing or ``--numpy`` is
given; both paths give identical tables. The exhaustive sweep of one function on one target
costs a few minutes of one core (tan: 256 chunks of 2^24 inputs at about 1.5 s each, the
kernel 0.05 s of that); ``--bits`` sweeps part of the patterns (x >= +0 for odd functions).

The two-argument functions (``pow``, ``atan2``) get a second table, one row per pair set of
``runtime/testkit/ulp_pairs.py``: ``grid`` (every sign/exponent pair of the two arguments,
512 x 512 cells, each with the same number of random mantissa pairs), ``renderer`` (pow with
x in [0, inf] and y in [-64, 64]; atan2 on [-1, 1]^2, next to the diagonals and the axes)
and ``special`` (every pair of special values; pow of negative bases to integer powers;
atan2 with a zero or infinite side). Sampled: ``--samples`` grid pairs (a quarter of that
on the renderer's domain, 1/64 special); with ``--exhaustive``, ``--pairs`` (2^28: 1024
mantissa pairs per exponent pair). The truth is libm's float64 pow/atan2 (within 2^-50 of
mpmath, ``tests/test_ulp_pairs.py``), and the worst pair is checked again against mpmath at
50 digits (column "max by mpmath", where mpmath is installed). The max and mean are over the
pairs whose rounded truth is finite (pow: and normal, where its bound holds); a truth that is
NaN or zero, or rounds to an infinity, must come out exactly, the sign of a zero included.

    python bench/ulp.py --exhaustive --functions pow,atan2 --targets scalar,avx2,avx512
"""

from __future__ import annotations

import argparse
import ctypes
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import rdsl  # noqa: E402
from rdsl.runtime.testkit.ulp import (  # noqa: E402
    BINARY, UNARY, Binary, float32_chunk, ulp_error, wrappers)
from rdsl.runtime.testkit.ulp_pairs import SETS  # noqa: E402

CHUNK = 1 << 24


LIBM = ["sin", "cos", "tan", "asin", "acos", "atan", "exp", "exp2", "log", "log2", "sqrt",
        "rsqrt", "erf", "erfinv"]  # the truths of ulp_stats.c, by index


def _native():
    """bench/ulp_stats.c built with cc (cached next to it in build/), or None without cc."""
    src = Path(__file__).with_name("ulp_stats.c")
    lib = Path(__file__).resolve().parent / "build" / "ulp_stats.so"
    if not lib.is_file() or lib.stat().st_mtime < src.stat().st_mtime:
        cc = shutil.which("cc")
        if cc is None:
            return None
        lib.parent.mkdir(exist_ok=True)
        subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(lib), str(src), "-lm"],
                       check=True)
    return ctypes.CDLL(str(lib))


def sweep_native(native, kernel, fn, patterns) -> dict:
    """sweep() with the truth and the statistics in C: same results, many times faster."""
    worst, worst_x, total, n, bad_special = 0.0, 0.0, 0.0, 0, 0
    out = np.zeros(5)
    fid = LIBM.index(fn.name) if fn.name in LIBM else -1
    for x in patterns:
        got = np.ascontiguousarray(kernel(x), np.float32)
        ref = np.zeros(1)
        if fid < 0:
            with np.errstate(all="ignore"):
                ref = np.ascontiguousarray(fn.truth(x.astype(np.float64)))
        p = ctypes.c_void_p
        native.ulp_stats(p(x.ctypes.data), p(got.ctypes.data), p(ref.ctypes.data),
                         ctypes.c_int64(x.size), ctypes.c_int(fid), ctypes.c_double(fn.lo),
                         ctypes.c_double(fn.hi), p(out.ctypes.data))
        if out[0] > worst:
            worst, worst_x = float(out[0]), float(out[1])
        total, n, bad_special = total + out[2], n + int(out[3]), bad_special + int(out[4])
    return {"max": worst, "mean": total / max(n, 1), "at": worst_x, "n": n,
            "special": bad_special}


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


def sweep2_native(native, kernel, fn: Binary, pairs) -> dict:
    """The two-argument sweep with the truth (libm's pow/atan2) and statistics in C."""
    worst, at, total, n, bad_special = 0.0, (0.0, 0.0), 0.0, 0, 0
    out = np.zeros(6)
    fid = [b.name for b in BINARY].index(fn.name)
    for x, y in pairs:
        x, y = np.ascontiguousarray(x), np.ascontiguousarray(y)
        got = np.ascontiguousarray(kernel(x, y), np.float32)
        p = ctypes.c_void_p
        native.ulp_stats2(p(x.ctypes.data), p(y.ctypes.data), p(got.ctypes.data),
                          ctypes.c_int64(x.size), ctypes.c_int(fid),
                          ctypes.c_int(fn.normal_only), p(out.ctypes.data))
        if out[0] > worst:
            worst, at = float(out[0]), (float(out[1]), float(out[2]))
        total, n, bad_special = total + out[3], n + int(out[4]), bad_special + int(out[5])
    return {"max": worst, "mean": total / max(n, 1), "at": at, "n": n, "special": bad_special}


def sweep2(kernel, fn: Binary, pairs) -> dict:
    """sweep2_native() in numpy: the same results, slower."""
    worst, at, total, n, bad_special = 0.0, (0.0, 0.0), 0.0, 0, 0
    for x, y in pairs:
        got = kernel(x, y).astype(np.float64)
        with np.errstate(all="ignore"):
            ref = fn.truth(x.astype(np.float64), y.astype(np.float64))
            ref32 = ref.astype(np.float32)
            tiny = np.finfo(np.float32).tiny if fn.normal_only else 0.0
            inside = np.isfinite(ref32) & (np.abs(ref32) >= tiny)
        if inside.any():
            e = ulp_error(got[inside], ref[inside])
            k = int(np.argmax(e))
            if e[k] > worst:
                worst, at = float(e[k]), (float(x[inside][k]), float(y[inside][k]))
            total, n = total + float(e[np.isfinite(e)].sum()), n + int(e.size)
        # NaN, zeros and overflows must come out exactly, the sign of a zero included
        special = ~np.isfinite(ref32) | (ref == 0)
        g, r, r32 = got[special], ref[special], ref32[special]
        ok = (np.isnan(g) & np.isnan(r)) | ((g == r32) & (np.signbit(g) == np.signbit(r)))
        bad_special += int(np.count_nonzero(~ok))
    return {"max": worst, "mean": total / max(n, 1), "at": at, "n": n, "special": bad_special}


def mpmath_error(fn: Binary, kernel, at: tuple[float, float]) -> str:
    """The worst pair's error again, against mpmath at 50 digits (the float64 truth checked)."""
    try:
        import mpmath
    except ImportError:
        return "-"
    x, y = (np.float32(v) for v in at)
    got = float(kernel(np.array([x]), np.array([y]))[0])
    with mpmath.workdps(50):
        a, b = mpmath.mpf(float(x)), mpmath.mpf(float(y))
        t = mpmath.power(a, b) if fn.name == "pow" else mpmath.atan2(a, b)
        if not mpmath.isfinite(t) or t == 0 or isinstance(t, mpmath.mpc):
            return "-"
        e = int(np.abs(np.float32(float(t))).view(np.uint32)) >> 23
        spacing = 2.0 ** (max(e, 1) - 150) if e < 255 else 2.0**104
        return f"{float(abs(mpmath.mpf(got) - t) / spacing):.3f}"


def pair_sizes(exhaustive: bool, samples: int, pairs: int) -> dict[str, int]:
    """Pairs per set: the grid gets n, the renderer's domain n / 4, the special sets n / 64."""
    n = pairs if exhaustive else samples
    return {"grid": n, "renderer": n // 4, "special": n // 64}


def patterns(exhaustive: bool, samples: int, seed: int, bits: str = "0:100000000"):
    if exhaustive:
        for span in bits.split(","):
            lo, hi = (int(b, 16) for b in span.split(":"))
            for start in range(lo, hi, CHUNK):
                yield float32_chunk(start, min(CHUNK, hi - start))
        return
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 1 << 32, samples, dtype=np.uint64).astype(np.uint32)
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 0.5, 1e-45, 3.4e38],
                       np.float32)
    yield np.concatenate([bits.view(np.float32), special])


def run_unary(args, chosen, native) -> bool:
    """The one-argument functions' table; True if a max is over its bound or a special wrong."""
    src = wrappers([u.name for u in chosen])
    mode = (("all 2^32 inputs" if args.bits == "0:100000000" else f"all bit patterns {args.bits}")
            if args.exhaustive else f"{args.samples} sampled bit patterns")
    print(f"ulp errors against float64, {mode}\n")
    print(f"| function | target | domain | max ulp | mean ulp | worst input | bound | "
          f"special mismatches | seconds |")
    print("|---|---|---|---|---|---|---|---|---|")
    failed = False
    for target in args.targets.split(","):
        mod = rdsl.jit(src, target=target)
        for fn in chosen:
            t0 = time.perf_counter()
            pats = patterns(args.exhaustive, args.samples, args.seed, args.bits)
            r = (sweep_native(native, mod[f"k_{fn.name}"], fn, pats) if native is not None
                 else sweep(mod[f"k_{fn.name}"], fn, pats))
            dt = time.perf_counter() - t0
            over = r["max"] > fn.bound or r["special"] > 0
            failed |= over
            print(f"| {fn.name} | {target} | [{fn.lo:.3g}, {fn.hi:.3g}] | {r['max']:.3f} | "
                  f"{r['mean']:.4f} | {r['at']!r} | {fn.bound} | {r['special']} | "
                  f"{dt:.1f} |{'  <-- over' if over else ''}", flush=True)
    return failed



def run_binary(args, chosen: list[Binary], native) -> bool:
    """The two-argument functions' table; True if a max is over its bound or a special wrong."""
    sizes = pair_sizes(args.exhaustive, args.samples, args.pairs)
    print(f"\ntwo-argument functions against float64 (libm), mpmath at the max; pairs per set: "
          + ", ".join(f"{k} {v}" for k, v in sizes.items()) + "\n")
    print("| function | target | pairs | domain | max ulp | mean ulp | worst (x, y) | "
          "max by mpmath | bound | special mismatches | seconds |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    failed = False
    for target in args.targets.split(","):
        mod = rdsl.jit(wrappers([b.name for b in chosen]), target=target)
        for fn in chosen:
            kernel = mod[f"k_{fn.name}"]
            for k, (name, gen) in enumerate(SETS.items()):
                t0 = time.perf_counter()
                rng = np.random.default_rng([args.seed, k])
                pairs = gen(fn.name, sizes[name], rng, CHUNK)
                r = (sweep2_native(native, kernel, fn, pairs) if native is not None
                     else sweep2(kernel, fn, pairs))
                dt = time.perf_counter() - t0
                over = r["max"] > fn.bound or r["special"] > 0
                failed |= over
                x, y = r["at"]
                print(f"| {fn.name} | {target} | {name} {r['n']} | {fn.domain} | "
                      f"{r['max']:.3f} | {r['mean']:.4f} | ({x!r}, {y!r}) | "
                      f"{mpmath_error(fn, kernel, r['at'])} | {fn.bound} | {r['special']} | "
                      f"{dt:.1f} |{'  <-- over' if over else ''}", flush=True)
    return failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--targets", default="scalar,host")
    ap.add_argument("--functions", default=",".join(u.name for u in [*UNARY, *BINARY]))
    ap.add_argument("--exhaustive", action="store_true", help="all 2^32 inputs")
    ap.add_argument("--bits", default="0:100000000",
                    help="with --exhaustive: the bit patterns swept, hex ranges LO:HI (HI "
                         "excluded), comma-separated; 0:80000000 is every x >= +0")
    ap.add_argument("--samples", type=int, default=1 << 22)
    ap.add_argument("--pairs", type=int, default=1 << 28,
                    help="with --exhaustive: pairs of the two-argument functions' grid set "
                         "(2^28: 1024 mantissa pairs per sign/exponent pair)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--numpy", action="store_true",
                    help="numpy's truth and statistics even where cc is present (slower)")
    args = ap.parse_args(argv)
    chosen = [u for u in UNARY if u.name in args.functions.split(",")]
    chosen2 = [b for b in BINARY if b.name in args.functions.split(",")]
    unknown = set(args.functions.split(",")) - {u.name for u in [*chosen, *chosen2]}
    if unknown:
        ap.error(f"unknown function(s): {', '.join(sorted(unknown))}")
    native = None if args.numpy else _native()
    failed = run_unary(args, chosen, native) if chosen else False
    if chosen2:
        failed |= run_binary(args, chosen2, native)
    return 1 if failed else 0

if __name__ == "__main__":
    sys.exit(main())
