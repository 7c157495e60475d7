"""The two-argument sweeps of bench/ulp.py: the pair sets cover what they say, the float64
truth is good enough (mpmath), and the C statistics agree with numpy's."""

from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.runtime.testkit.ulp import BINARY, wrappers
from rdsl.runtime.testkit.ulp_pairs import CELLS, SETS, SPECIAL


def _bench():
    path = Path(rdsl.__file__).parent / "bench" / "ulp.py"
    spec = importlib.util.spec_from_file_location("bench_ulp_pairs", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _all(gen, fn: str, n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    parts = list(gen(fn, n, np.random.default_rng(seed), 1 << 20))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def test_grid_gives_every_sign_exponent_pair_the_same_count():
    x, y = _all(SETS["grid"], "atan2", 2 * CELLS)
    hx = x.view(np.uint32) >> 23
    hy = y.view(np.uint32) >> 23
    counts = np.bincount((hx << 9 | hy).astype(np.int64), minlength=CELLS)
    assert np.all(counts == 2)
    # zeros, infinities and NaNs are all there, with both signs
    assert np.any(x == 0) and np.any(np.signbit(x[x == 0])) and np.any(x == -np.inf)
    assert np.any(np.isnan(y)) and np.any(y == np.inf)


def test_renderer_sets_stay_on_the_renderers_domain():
    x, y = _all(SETS["renderer"], "pow", 200_000)
    assert np.all(x >= 0) and np.any(x == np.inf) and np.any((x > 0) & (x < 1.2e-38))
    assert np.all(np.abs(y) <= 64) and np.any(y == 64) and np.any(y == np.float32(1 / 2.4))
    assert np.any((y != 0) & (np.abs(y) < 1e-38))  # denormal exponents
    y2, x2 = _all(SETS["renderer"], "atan2", 200_000)
    assert np.all(np.abs(y2) <= 1) and np.all(np.abs(x2) <= 1)
    assert np.any(np.abs(y2) < 1e-30 * np.abs(x2)) and np.any(np.abs(x2) < 1e-30 * np.abs(y2))


def test_special_set_has_every_pair_of_special_values():
    x, y = _all(SETS["special"], "pow", 10_000)
    seen = {(a.tobytes(), b.tobytes()) for a, b in zip(x, y)}
    assert all((a.tobytes(), b.tobytes()) in seen for a in SPECIAL for b in SPECIAL)
    # pow: negative bases with integer exponents, odd ones past 2^23 included
    neg = (x < 0) & (y == np.floor(y))
    assert np.count_nonzero(neg) > 1000 and np.any(np.abs(y[neg]) > 2**23)


@pytest.mark.parametrize("name", ["pow", "atan2"])
def test_float64_truth_agrees_with_mpmath(name):
    """float64 pow/atan2 of float32 arguments are within 2^-50 of mpmath's (50 digits), so the
    ulp errors they give are the float32 functions' own to ~1e-6 ulp."""
    import mpmath
    x, y = _all(SETS["grid"], name, 4000, seed=5)
    rx, ry = _all(SETS["renderer"], name, 2000, seed=6)
    x, y = np.concatenate([x, rx]), np.concatenate([y, ry])
    fn = next(b for b in BINARY if b.name == name)
    with np.errstate(all="ignore"):
        ref = fn.truth(x.astype(np.float64), y.astype(np.float64))
    ok = np.isfinite(ref) & (np.abs(ref) > 1e-300) & (np.abs(ref) < 1e300)
    worst = 0.0
    with mpmath.workdps(50):
        for a, b, r in zip(x[ok], y[ok], ref[ok]):
            t = (mpmath.power(mpmath.mpf(float(a)), float(b)) if name == "pow"
                 else mpmath.atan2(float(a), float(b)))
            worst = max(worst, float(abs((mpmath.mpf(float(r)) - t) / t)))
    assert np.count_nonzero(ok) > 2000 and worst < 2.0**-50


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler (cc) for ulp_stats.c")
@pytest.mark.parametrize("fn", BINARY, ids=lambda b: b.name)
def test_c_statistics_match_numpys(fn):
    """sweep2_native (C, libm's truth) and sweep2 (numpy) give the same table row."""
    bench = _bench()
    kernel = rdsl.jit(wrappers([fn.name]), target="scalar")[f"k_{fn.name}"]
    for name, gen in SETS.items():
        def pairs():
            return gen(fn.name, 30_000, np.random.default_rng(9), 1 << 14)
        c = bench.sweep2_native(bench._native(), kernel, fn, pairs())
        py = bench.sweep2(kernel, fn, pairs())
        assert c["n"] == py["n"] and c["special"] == py["special"] and c["at"] == py["at"]
        assert c["max"] == pytest.approx(py["max"], rel=1e-12), name
        assert c["mean"] == pytest.approx(py["mean"], rel=1e-9), name


def test_a_wrong_special_value_is_counted():
    """The sweep is not blind: a kernel that loses the sign of atan2's zeros, or returns a
    finite value where pow overflows, is caught."""
    bench = _bench()
    atan2 = next(b for b in BINARY if b.name == "atan2")
    y = np.array([0.0, -0.0, 1.0], np.float32)
    x = np.array([1.0, 1.0, 1.0], np.float32)
    r = bench.sweep2(lambda a, b: np.abs(np.arctan2(a, b)), atan2, [(y, x)])
    assert r["special"] == 1
    pow_ = next(b for b in BINARY if b.name == "pow")
    x, y = np.array([10.0, 2.0], np.float32), np.array([40.0, 3.0], np.float32)
    r = bench.sweep2(lambda a, b: np.minimum(np.power(a.astype(np.float64), b), 3e38).astype(
        np.float32), pow_, [(x, y)])
    assert r["special"] == 1  # 10^40 rounds to inf in float32: FLT_MAX is wrong


@pytest.mark.parametrize("target", ["scalar", "host"])
def test_float_remainder_is_exact(target):
    """The stdlib's other two-argument float function, ``x % y``, is C's fmodf (exact, so no
    ulp bound to sweep): bit for bit over the exponent grid and the special pairs."""
    kernel = rdsl.jit("fn k_rem(x: Float, y: Float) -> Float { return x % y; }",
                      target=target)["k_rem"]
    for name in ("grid", "special"):
        x, y = _all(SETS[name], "atan2", 1 << 18)
        with np.errstate(all="ignore"):
            got, ref = kernel(x, y), np.fmod(x, y)
        same = (got.view(np.uint32) == ref.view(np.uint32)) | (np.isnan(got) & np.isnan(ref))
        assert same.all(), (x[~same][:3], y[~same][:3], got[~same][:3])
