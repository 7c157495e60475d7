"""What the checks of every plugin kind share: the local shading frame (normal +z) and its
surfaces, directions by angle, fixed seeds, and the parameter sweep of the NaN/Inf checks."""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .harness import Declaration
from .report import FAIL, PASS, SKIP, Row

f32 = np.float32
# incident angles of the NaN/Inf sweep: normal, near-normal, grazing (1.5707 and pi / 2
# exactly), and the same from below the surface
GRAZING = (0.0, 1e-4, 1.5, 1.5707, np.pi / 2, np.pi - 1e-4, np.pi - 1.5707)


@dataclass
class Options:
    """How hard to test: ``samples`` per chi-square / energy case, ``params`` the plugin's
    parameter values (the rest take their defaults), ``p_min`` the chi-square threshold."""

    samples: int = 200_000
    params: dict[str, Any] = field(default_factory=dict)
    p_min: float = 1e-3


def rng(*key: Any) -> np.random.Generator:
    """A fixed seed per case: the same run gives the same table."""
    return np.random.default_rng(zlib.crc32(repr(key).encode()))


def sph(theta: Any, phi: Any) -> np.ndarray:
    """Unit directions at polar angle theta (from +z) and azimuth phi, float32."""
    theta, phi = np.asarray(theta, np.float64), np.asarray(phi, np.float64)
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta) + 0 * phi],
                    -1).astype(f32)


def wi_at(theta: float, phi: float = 0.4) -> np.ndarray:
    return sph(theta, phi)


def tile(v: Any, n: int) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(v, f32), (n, 3)))


def surface(wi: np.ndarray, uv: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Surfaces at the origin with normal +z seen from directions ``wi`` (n, 3)."""
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    uv = np.zeros((n, 2), f32) if uv is None else np.ascontiguousarray(uv, f32)
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": uv,
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32),
            "valid": np.ones(n, bool)}


def sphere_sweep(n: int, seed: Any) -> np.ndarray:
    """n directions: random over the sphere, then the poles and exactly tangent ones."""
    gen = rng("sweep", seed)
    special = [[0, 0, 1], [1, 0, 0], [0, 1, 1e-7], [0, 0, -1], [0, 1, -1e-7], [-1, 0, 0]]
    return np.concatenate([sph(np.arccos(gen.uniform(-1, 1, n - 6)),
                               gen.uniform(0, 2 * np.pi, n - 6)), special]).astype(f32)


def _extremes(ptype: str, value: Any) -> list[Any]:
    """Values at the edges of a parameter's plausible range, from its type and default:
    a Texture (a reflectance, a transmittance) 0 and 1; a Float or a Spectrum in (0, 1] (a
    roughness, a weight, an extinction coefficient) 1e-4 and 1, above 1 (an index of
    refraction) 1 and 1.0001; booleans both.  Ints (enumerations), vectors and parameters
    at 0 or below (off, or a "same as" sentinel) keep their values: what their edges are is
    the plugin's own business."""
    if ptype == "Texture":
        return [0.0, 1.0]
    if ptype == "Bool":
        return [not value]
    if ptype in ("Float", "Spectrum") and isinstance(value, (int, float)):
        if 0 < value <= 1:
            return [1e-4, 1.0]
        if value > 1:
            return [1.0, 1.0001]
    return []


def extreme_params(decl: Declaration, base: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """``base`` and then ``base`` with one parameter at a time at an extreme value."""
    yield dict(base)
    for p in decl.params:
        value = base.get(p.name, p.default)
        for x in _extremes(p.type, value):
            if x != value:
                yield {**base, p.name: x}


def describe(params: dict[str, Any], base: dict[str, Any]) -> str:
    """The parameters that differ from ``base``, for a row's case or note."""
    diff = {k: v for k, v in params.items() if base.get(k, object()) != v}
    return ", ".join(f"{k}={v}" for k, v in diff.items()) or "defaults"


def finite_rows(decl: Declaration, opts: Options, bad: Callable[[dict[str, Any]], str],
                what: str) -> list[Row]:
    """Two rows: ``bad(params)`` (what is NaN, infinite or negative, or '') for the given
    parameters, then for each parameter in turn at an extreme value; ``what`` names the
    cases each call covers."""
    sweeps = list(extreme_params(decl, opts.params))
    rows = []
    for label, cases in (("given params", sweeps[:1]), ("extreme params", sweeps[1:])):
        if not cases:
            rows.append(Row("finite, >= 0", label, "-", "-", SKIP, "no parameter to vary"))
            continue
        why = ""
        for params in cases:
            why = bad(params)
            if why:
                why = f"{why} ({describe(params, opts.params)})"
                break
        rows.append(Row("finite, >= 0", label, f"{len(cases)} x {what}", "no NaN/Inf/< 0",
                        FAIL if why else PASS, why))
    return rows
