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


def ulp_error(got: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per element: |got - ref| in float32 ulp at the correctly rounded ``ref``."""
    got = np.asarray(got, np.float64)
    ref = np.asarray(ref, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        ref32 = ref.astype(np.float32)
        spacing = np.spacing(np.abs(ref32)).astype(np.float64)
        spacing = np.maximum(np.where(np.isfinite(spacing), spacing, 2.0**104), 2.0**-149)
        err = np.abs(got - ref) / spacing
    same_special = (np.isnan(got) & np.isnan(ref)) | (
        np.isinf(got) & np.isinf(ref32) & (np.sign(got) == np.sign(ref)))
    err = np.where(same_special, 0.0, err)
    return np.where(np.isnan(got) != np.isnan(ref), np.inf, err)


def _erfinv(y: np.ndarray) -> np.ndarray:
    from scipy.special import erfinv

    return erfinv(y)


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
BOUNDS = {u.name: u.bound for u in UNARY}


def wrappers(names: list[str]) -> str:
    """An rdsl program with one kernel ``k_NAME(x) -> Float`` per function."""
    return "\n".join(f"fn k_{n}(x: Float) -> Float {{ return {n}(x); }}" for n in names)


def float32_chunk(start: int, count: int) -> np.ndarray:
    """The float32 values whose bit patterns are ``start .. start + count - 1``."""
    return np.arange(start, start + count, dtype=np.uint64).astype(np.uint32).view(np.float32)
