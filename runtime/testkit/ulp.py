"""Errors of float32 math in ulp, for ``bench/ulp.py`` and ``tests/test_stdlib_math.py``.

An error is ``|got - truth|`` in units of the float32 spacing at the correctly rounded
truth (``np.spacing`` of the float32 result). The truth is numpy's float64 function of the
same float32 input: float64 results are within half a float64 ulp, 2^-29 of a float32 ulp,
so the measured error is the float32 function's own to well under 1e-6 ulp. NaN must match
NaN and infinities must match exactly (0 ulp); a NaN where the truth has none is inf ulp.

:data:`UNARY` lists the stdlib's one-argument functions with their truth and the domain on
which ``stdlib/math.rdsl`` documents its bound (``BOUNDS``); outside it a function returns
what its comment says (NaN for asin(2), say), and the sweep checks that too.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


# float32 spacing by biased exponent: 2^(e - 150), denormals 2^-149, inf/NaN 2^104
_SPACING = np.ldexp(1.0, np.maximum(np.arange(256), 1) - 150)
_SPACING[255] = 2.0**104


def ulp_error(got: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per element: |got - ref| in float32 ulp at the correctly rounded ``ref``."""
    got = np.asarray(got, np.float64)
    ref = np.asarray(ref, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        ref32 = ref.astype(np.float32)
        spacing = _SPACING[(ref32.view(np.uint32) >> 23) & 0xff]
        err = np.abs(got - ref) / spacing
    # NaN and infinities (rare): fixed up on their own, so the sweep stays fast
    odd = np.flatnonzero(~np.isfinite(got) | ~np.isfinite(ref32))
    if odd.size:
        g, r, r32, e = got.flat[odd], ref.flat[odd], ref32.flat[odd], err.flat[odd]
        same_special = (np.isnan(g) & np.isnan(r)) | (
            np.isinf(g) & np.isinf(r32) & (np.sign(g) == np.sign(r)))
        e = np.where(same_special, 0.0, e)
        err.flat[odd] = np.where(np.isnan(g) != np.isnan(r), np.inf, e)
    return err


def _erfinv(y: np.ndarray) -> np.ndarray:
    from scipy.special import erfinv

    # outside [-1, 1] scipy's domain-error path is slow: NaN there directly
    out = np.full(np.shape(y), np.nan)
    m = np.abs(y) <= 1
    out[m] = erfinv(y[m])
    return out


def _erf(x: np.ndarray) -> np.ndarray:
    from scipy.special import erf

    return erf(x)


@dataclass(frozen=True)
class Unary:
    """A stdlib function of one Float, its float64 truth and its documented domain."""

    name: str
    truth: Callable[[np.ndarray], np.ndarray]
    lo: float  # the documented bound holds for lo <= x <= hi
    hi: float
    bound: float  # documented max error (ulp) on [lo, hi]


F32_MAX = float(np.finfo(np.float32).max)
UNARY = [
    Unary("sin", np.sin, -12000.0, 12000.0, 1.0),
    Unary("cos", np.cos, -12000.0, 12000.0, 1.0),
    Unary("tan", np.tan, -12000.0, 12000.0, 1.0),
    Unary("asin", np.arcsin, -1.0, 1.0, 1.0),
    Unary("acos", np.arccos, -1.0, 1.0, 1.0),
    Unary("atan", np.arctan, -F32_MAX, F32_MAX, 1.0),
    Unary("exp", np.exp, -F32_MAX, F32_MAX, 1.0),
    Unary("exp2", np.exp2, -F32_MAX, F32_MAX, 1.0),
    Unary("log", np.log, 0.0, F32_MAX, 1.0),
    Unary("log2", np.log2, 0.0, F32_MAX, 1.0),
    Unary("sqrt", np.sqrt, 0.0, F32_MAX, 0.5),
    Unary("rsqrt", lambda x: 1.0 / np.sqrt(x), 0.0, F32_MAX, 1.0),
    Unary("erf", _erf, -F32_MAX, F32_MAX, 1.0),
    Unary("erfinv", _erfinv, -1.0, 1.0, 1.0),
]


@dataclass(frozen=True)
class Binary:
    """A stdlib function of two Floats, its float64 truth and where its bound holds."""

    name: str
    truth: Callable[[np.ndarray, np.ndarray], np.ndarray]
    normal_only: bool  # the bound holds where the rounded truth is normal (else: finite)
    bound: float  # documented max error (ulp) there
    domain: str


BINARY = [
    Binary("pow", np.power, True, 1.0, "normal results"),
    Binary("atan2", np.arctan2, False, 1.0, "all floats"),
]
BOUNDS = {f.name: f.bound for f in [*UNARY, *BINARY]}


def wrappers(names: list[str]) -> str:
    """An rdsl program with one kernel ``k_NAME(x) -> Float`` (``k_NAME(x, y)`` for the
    functions of :data:`BINARY`) per function."""
    two = {b.name for b in BINARY}
    return "\n".join(f"fn k_{n}(x: Float, y: Float) -> Float {{ return {n}(x, y); }}"
                     if n in two else f"fn k_{n}(x: Float) -> Float {{ return {n}(x); }}"
                     for n in names)


def float32_chunk(start: int, count: int) -> np.ndarray:
    """The float32 values whose bit patterns are ``start .. start + count - 1``."""
    return np.arange(start, start + count, dtype=np.uint64).astype(np.uint32).view(np.float32)
