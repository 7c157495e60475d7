"""Float32 argument pairs for the ulp sweeps of the two-argument functions (``bench/ulp.py``).

The 2^64 pairs cannot all be tried, so each set covers its part of the plane evenly:

- ``grid``: every (sign, biased exponent) of x against every one of y (512 x 512 cells,
  denormals, zeros, infinities and NaNs included), each cell with the same number of random
  mantissa pairs (one mantissa in 16 is zero: powers of two, zeros and infinities);
- ``renderer``: where a renderer calls them. pow: x in [0, inf] (every exponent evenly) and
  y in [-64, 64] (uniform, log-uniform magnitudes down to the denormals, integers and
  half-integers, and the exponents of gamma curves and Phong lobes); atan2: the components of
  directions, (y, x) in [-1, 1]^2 uniformly, next to the diagonals and next to the axes;
- ``special``: every pair of :data:`SPECIAL` (signed zeros, infinities, NaN, 1, odd and even
  integers, the ends of the range), then pow with x of either sign and integer y (C's sign
  rules for negative bases), atan2 with one argument zero or infinite.

Each generator yields ``(x, y)`` float32 chunks of at most ``chunk`` pairs, ``n`` in all.
"""

from __future__ import annotations

from typing import Callable, Iterator

import numpy as np

CELLS = 512 * 512
F32_MAX = float(np.finfo(np.float32).max)
SPECIAL = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 0.5, -0.5, 2.0, -2.0, 3.0,
                    -3.0, 2.5, -2.5, 1e-45, -1e-45, 1.1754944e-38, F32_MAX, -F32_MAX,
                    16777215.0, -16777215.0, 16777216.0, -3e9, 0.99999994, 1.0000001, 64.0,
                    -64.0, 1e-20, 1e20], np.float32)
# exponents of sRGB/gamma curves, Phong and Blinn lobes, Schlick's Fresnel, roughness maps
COMMON_Y = np.array([2.2, 1 / 2.2, 2.4, 1 / 2.4, 0.5, 1 / 3, 1.5, 2, 3, 4, 5, 10, 20, 32, 50,
                     64, 0.2, 0.25, 0.1, -0.5, -1, -2, -1.5, 1 / 64], np.float32)
Pairs = Iterator[tuple[np.ndarray, np.ndarray]]


def _mantissas(rng: np.random.Generator, n: int) -> np.ndarray:
    m = rng.integers(0, 1 << 23, n, dtype=np.uint32)
    m[rng.random(n) < 1 / 16] = 0
    return m


def _floats(high_bits: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Floats with the given sign/exponent bits (9 of them) and random mantissas."""
    return ((high_bits.astype(np.uint32) << 23) | _mantissas(rng, high_bits.size)).view(
        np.float32)


def _chunks(n: int, chunk: int) -> Iterator[tuple[int, int]]:
    for start in range(0, n, chunk):
        yield start, min(chunk, n - start)


def grid(fn: str, n: int, rng: np.random.Generator, chunk: int) -> Pairs:
    """Every sign/exponent pair equally often (when n >= CELLS; else random cells)."""
    for start, m in _chunks(n, chunk):
        cells = (np.arange(start, start + m) % CELLS if n >= CELLS
                 else rng.integers(0, CELLS, m))
        yield _floats(cells >> 9, rng), _floats(cells & 511, rng)


def _signed(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.where(rng.random(n) < 0.5, -1.0, 1.0)


def renderer(fn: str, n: int, rng: np.random.Generator, chunk: int) -> Pairs:
    """pow: x in [0, inf], y in [-64, 64]; atan2: (y, x) in [-1, 1]^2."""
    for _, m in _chunks(n, chunk):
        kind = rng.integers(0, 4, m)
        if fn == "pow":
            x = _floats(rng.integers(0, 256, m), rng)
            x[x.view(np.uint32) > 0x7f800000] = np.inf  # no NaN: x in [0, inf]
            y = np.select([kind == 0, kind == 1, kind == 2],
                          [rng.uniform(-64, 64, m),
                           _signed(rng, m) * np.exp2(rng.uniform(-150, 6, m)),
                           rng.integers(-128, 129, m) / 2],
                          rng.choice(COMMON_Y, m).astype(np.float64))
            yield x, y.astype(np.float32)
            continue
        a = rng.uniform(-1, 1, m)
        # kind 1: next to the diagonals (|y| = |x| (1 + k 2^-23)); 2, 3: next to an axis
        b = np.select([kind == 0, kind == 1],
                      [rng.uniform(-1, 1, m),
                       _signed(rng, m) * a * (1 + rng.integers(-64, 65, m) * 2.0**-23)],
                      _signed(rng, m) * np.abs(a) * np.exp2(rng.uniform(-150, 0, m)))
        swap = kind == 3
        yield np.where(swap, a, b).astype(np.float32), np.where(swap, b, a).astype(np.float32)


def special(fn: str, n: int, rng: np.random.Generator, chunk: int) -> Pairs:
    """Every pair of SPECIAL, then pow(x, integer y) / atan2 with a zero or infinite side."""
    sx, sy = (a.ravel() for a in np.meshgrid(SPECIAL, SPECIAL))
    yield sx, sy
    for _, m in _chunks(max(n - sx.size, 0), chunk):
        x = _floats(rng.integers(0, 512, m), rng)
        if fn == "pow":
            odd = rng.integers(1 << 22, 1 << 23, m) * 2 + 1  # odd integers up to 2^24
            y = np.where(rng.random(m) < 0.75, rng.integers(-64, 65, m),
                         _signed(rng, m) * odd).astype(np.float32)
            yield x, y
            continue
        y = rng.choice(SPECIAL[:5], m)
        swap = rng.random(m) < 0.5
        yield np.where(swap, y, x), np.where(swap, x, y)


SETS: dict[str, Callable[[str, int, np.random.Generator, int], Pairs]] = {
    "grid": grid, "renderer": renderer, "special": special}
