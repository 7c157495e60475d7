"""Checks and sample counts of the scene's sampler (Mitsuba 3's samplers/*.cpp).

``orthogonal`` needs the square of a prime and ``ldsampler`` the square of a power of two:
as Mitsuba's constructors do, a count that is neither is rounded up to the next one with a
warning, both the sampler's ``sample_count`` and the ``spp`` a render asks for
(:func:`sample_count`).  The per-sample algorithms are in stdlib/render/sampler.rdsl.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from .errors import scene_error


def _is_prime(x: int) -> bool:
    return x >= 2 and all(x % i for i in range(2, int(x ** 0.5) + 1))


def valid_count(ptype: str, n: int) -> int:
    """The smallest count at least ``n`` that sampler ``ptype`` can stratify (Mitsuba's
    rounding: ``orthogonal`` p^2 with p prime, ``ldsampler`` 4^k with k >= 1)."""
    if ptype == "orthogonal":
        r = 2
        while r * r < n or not _is_prime(r):
            r += 1
        return r * r
    if ptype == "ldsampler":
        r = 2
        while r * r < n:
            r *= 2
        return r * r
    return n


def requested_samples(spp: Any, seed: Any, default_spp: int, default_seed: int
                      ) -> tuple[int, int]:
    """A call's ``spp`` and ``seed`` (None: the scene's), checked: ``spp`` a whole number,
    1 or more, ``seed`` a whole number in 0 .. 2^32 - 1 (Mitsuba's ``seed`` is a UInt32).
    A bad value is a ``ValueError`` naming it, not a black image (a negative count) or
    a seed silently wrapped."""
    def whole(x: Any) -> bool:
        return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))

    spp = default_spp if spp is None else spp
    if not whole(spp) or spp < 1:
        raise ValueError(f"spp: expected a whole number of samples per pixel, 1 or more, "
                         f"got {spp!r}")
    seed = default_seed if seed is None else seed
    if not whole(seed) or not 0 <= seed < 1 << 32:
        raise ValueError(f"seed: expected a whole number in 0 .. 2^32 - 1, got {seed!r}")
    return int(spp), int(seed)


def sample_count(sampler: Any, n: int, loc: Loc | None = None) -> int:
    """``n`` samples per pixel as ``sampler`` can draw them, with a warning when rounded."""
    count = valid_count(sampler.type, n)
    if count != n:
        where = loc or sampler.loc
        what = ("the square of a prime" if sampler.type == "orthogonal"
                else "the square of a power of two")
        prefix = f"{where.file}:{where.line}: " if where is not None else ""
        warnings.warn(f"{prefix}{sampler.type}: the sample count should be {what}; "
                      f"rounding {n} to {count}", stacklevel=3)
    return count


def finish_sampler(obj: Any, loc: Any) -> None:
    """The loader's checks of a sampler; ``loc(name)`` is the line of parameter ``name``."""
    p = obj.params
    if p["sample_count"] <= 0:
        raise scene_error("sampler: 'sample_count' must be positive", loc("sample_count"))
    if p.get("strength", 2) != 2:
        raise scene_error(f"orthogonal: 'strength' is {p['strength']}; rdsl builds orthogonal "
                          "arrays of strength 2 only (Bose's construction, Mitsuba's default)",
                          loc("strength"))
    if p.get("seed", 0) < 0:
        raise scene_error("sampler: 'seed' must be >= 0", loc("seed"))
    p["sample_count"] = sample_count(obj, p["sample_count"], loc("sample_count"))


def attach_samplers(sensors: list[Any], samplers: list[Any], default: Callable[[], Any]) -> None:
    """Give each sensor without a nested ``<sampler>`` the one declared at the scene's top
    level, as Mitsuba's documentation scenes write it (Mitsuba 3.9 itself loads such a
    sampler but renders with the sensor's default); ``default()`` makes the independent one."""
    if len(samplers) > 1:
        raise scene_error("the scene declares more than one <sampler> outside its sensors",
                          samplers[1].loc)
    for sensor in sensors:
        if sensor.sampler is None:
            sensor.sampler = samplers[0] if samplers else default()
