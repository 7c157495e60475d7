"""Fits the polynomials of stdlib/math.rdsl: run it to reproduce their coefficients.

    python tools/fit_math.py            # every fit, as rdsl-ready float32 literals
    python tools/fit_math.py tan erf    # some of them

Each fit is a near-minimax polynomial in float64 (Lawson's iteratively reweighted least
squares on a dense grid of the reduced interval, weighted so that the error is measured
relative to the function's result, i.e. in ulp), then rounded to float32 coefficient by
coefficient from the lowest degree up, refitting the remaining ones after each rounding so
that the float32 polynomial stays near-minimax. The truth comes from mpmath at 40 digits
where numpy's float64 functions are not accurate enough (erfinv's tail).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Fit:
    """g(t) ~ sum c_k t^k on t in [lo, hi], error weighted by weight(t)."""

    name: str
    lo: float
    hi: float
    degree: int
    target: Callable[[np.ndarray], np.ndarray]
    weight: Callable[[np.ndarray], np.ndarray]
    fixed: tuple[float, ...] = ()  # leading coefficients fixed beforehand (c0, c1, ...)


def _lawson(t, g, w, degree, fixed, iters=60):
    k0 = len(fixed)
    rest = g - sum(c * t**k for k, c in enumerate(fixed))
    a = np.stack([t**k for k in range(k0, degree + 1)], axis=1)
    lw = np.ones_like(t)
    for _ in range(iters):
        sw = np.sqrt(lw) * w
        c, *_ = np.linalg.lstsq(a * sw[:, None], rest * sw, rcond=None)
        err = np.abs(a @ c - rest) * w
        lw = lw * err
        lw /= lw.sum()
    return list(fixed) + list(c)


def fit(f: Fit, n: int = 20000) -> tuple[list[float], float]:
    """float32 coefficients, lowest degree first, and their max weighted error."""
    # Chebyshev-spaced grid: minimax extrema crowd at the ends
    t = (f.lo + f.hi) / 2 + (f.hi - f.lo) / 2 * np.cos(np.linspace(np.pi, 0, n))
    g, w = f.target(t), f.weight(t)
    coeffs = [float(np.float32(c)) for c in f.fixed]
    for k in range(len(f.fixed), f.degree + 1):
        c = _lawson(t, g, w, f.degree, coeffs)
        coeffs.append(float(np.float32(c[k])))
    err = np.abs(sum(c * t**k for k, c in enumerate(coeffs)) - g) * w
    return coeffs, float(err.max())


def _rel(f):
    """Weight for an error relative to f, in units of 2^-24 (about 1 to 2 ulp)."""
    return lambda t: 2.0**24 / np.abs(f(t))


def _tan_tail(z):
    r = np.sqrt(z)
    return (np.tan(r) - r) / (r * z)


def _asin_tail(z):
    w = np.sqrt(z)
    return (np.arcsin(w) - w) / (w * z)


def _asin_weight(z):
    # asin(w) for |x| <= 1/2; pi/2 - 2 asin(w) for |x| > 1/2, whichever is worse
    w = np.sqrt(z)
    return 2.0**24 * w * z * np.maximum(1 / np.arcsin(w), 2 / (np.pi / 2 - 2 * np.arcsin(w)))


def _atan_tail(t):
    u = np.sqrt(t)
    return (np.arctan(u) - u) / (u * t)


def _atan_weight(t):
    # atan(u) for |x| <= 1/2, pi/4 +- atan(u) (|u| <= 1/3) up to |x| = 2, pi/2 - atan(u) above
    u = np.sqrt(t)
    return 2.0**24 * u * t * np.maximum(1 / np.arctan(u), 1 / (np.pi / 4 - np.arctan(u)))


def _erfcx(y):
    from scipy.special import erfcx

    return erfcx(y)


def _erf_piece(c):
    """erf(c + s) = e0 + d1 s + s G(s) with e0 = erf(c) and d1 the float32 erf'(c)."""
    from scipy.special import erf

    d1 = float(np.float32(2 / np.sqrt(np.pi) * np.exp(-c * c)))
    e0 = float(erf(c))

    def g(s):
        s = np.where(s == 0, 1e-12, s)
        return (erf(c + s) - e0 - d1 * s) / s

    return g, (lambda s: 2.0**24 * np.abs(s) / erf(c + s))


FITS = {
    # tan r = r + r^3 P(r^2), |r| <= pi/4 (+ the slack of the rounded reduction)
    "tan": Fit("tan", 1e-6, 0.7854**2, 6, _tan_tail,
               lambda z: np.sqrt(z) * z * _rel(lambda z: np.tan(np.sqrt(z)))(z)),
    # asin w = w + w^3 P(w^2), |w| <= 1/2
    # atan u = u + u^3 P(u^2), |u| <= 1/2
    "atan": Fit("atan", 1e-6, 0.25, 5, _atan_tail, _atan_weight),
    # erf(c + s), |s| <= 1/4, on [1/2, 1] (c = 3/4) and [1, 3/2] (c = 5/4)
    "erf075": Fit("erf075", -0.25, 0.25, 6, *_erf_piece(0.75)),
    "erf125": Fit("erf125", -0.25, 0.25, 6, *_erf_piece(1.25)),
    # erfcx(2.75 + s) = e^(y^2) erfc(y), y in [3/2, 4] (erfinv's Newton step)
    "erfcx": Fit("erfcx", -1.25, 1.25, 10, lambda s: _erfcx(2.75 + s),
                 lambda s: 2.0**24 / _erfcx(2.75 + s)),
    "asin": Fit("asin", 1e-6, 0.25, 5, _asin_tail, _asin_weight),
}


def main(argv: list[str]) -> int:
    for name in argv or list(FITS):
        coeffs, err = fit(FITS[name])
        lits = ", ".join(f"{np.float32(c)!r}".removeprefix("np.float32(").rstrip(")")
                         for c in coeffs)
        print(f"{name}: max error {err:.4f} x 2^-24 relative (float64 evaluation)\n  {lits}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
