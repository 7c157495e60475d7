"""Fit the sRGB -> spectrum table of Jakob & Hanika (2019), vectorised in numpy.

    W. Jakob, J. Hanika, "A Low-Dimensional Function Space for Efficient Spectral Upsampling",
    Computer Graphics Forum 38(2), 2019.

A reflectance is ``s(l) = sigmoid(c0 l^2 + c1 l + c2)`` with ``sigmoid(x) = 1/2 + x / (2
sqrt(1 + x^2))``. For every cell of a ``3 x res^3`` grid over linear sRGB we find the
coefficients whose colour under illuminant D65 matches the cell's colour, minimising the CIELAB
difference (relative to the D65 white) by Gauss-Newton, as the reference ``rgb2spec_opt`` does:

* Colours are integrated against the CIE 1931 curves times D65 (both the 5 nm tables in
  ``stdlib/data/spectra``, linearly interpolated) with composite Simpson 3/8 on 283 points
  (three per 5 nm step), D65 normalised so that white has Y = 1.
* The fit runs in the normalised wavelength ``t = (l - 360) / 470``, which keeps the 3x3
  Newton systems well conditioned; the stored coefficients are re-expanded for ``l`` in nm,
  the convention of Mitsuba's ``srgb.coeff`` and of :func:`rdsl.core.spectral.eval_coeffs`.
* Table layout (rgb2spec's): ``data[m, k, j, i]`` holds the cell whose largest component ``m``
  is ``scale[k] = smoothstep(smoothstep(k / (res - 1)))`` and whose components ``(m + 1) % 3``
  and ``(m + 2) % 3`` are ``i / (res - 1)`` and ``j / (res - 1)`` times that.
* Each (m, j, i) column is solved along the scale axis by continuation: from zero coefficients
  at ``k = res // 5``, each solution seeds the next brighter cell, then again from zero down to
  ``k = 0``. All columns advance together, so one step is a batch of ``3 res^2`` solves.

Where rgb2spec takes at most 15 undamped Gauss-Newton steps and rescales coefficients above
200, which leaves some dark and near-white cells unconverged, we use Levenberg-Marquardt
(Gauss-Newton with per-cell adaptive damping, analytic Jacobian) until the squared Lab
residual is below 1e-10 or no step improves it.

Run ``python -m rdsl.tools.rgb2spec_opt --res 64 --out stdlib/data/spectra/srgb_rgb2spec.npz``
to regenerate the committed table (about a minute on one core).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..core import spectral

SUBSTEPS = 3          # quadrature points per 5 nm interval (Simpson 3/8 needs a multiple of 3)
MAX_ITERATIONS = 100
TOLERANCE = 1e-10     # on the squared CIELAB residual
INITIAL_DAMPING = 1e-3
MIN_DAMPING = 1e-9
MAX_DAMPING = 1e12    # a cell whose step is still rejected at this damping has converged

# Linear sRGB -> XYZ, Mitsuba's srgb_to_xyz() (the inverse of XYZ_TO_SRGB to 6 digits).
SRGB_TO_XYZ = np.array([
    [0.412453, 0.357580, 0.180423],
    [0.212671, 0.715160, 0.072169],
    [0.019334, 0.119193, 0.950227],
])

_LAB_DELTA = 6.0 / 29.0
_LAB_ROWS = np.array([[0.0, 116.0, 0.0], [500.0, -500.0, 0.0], [0.0, 200.0, -200.0]])


@dataclass(frozen=True)
class Quadrature:
    """Weights that turn a spectrum sampled at ``t`` into linear sRGB under D65."""

    t: np.ndarray          # (n,) normalised wavelengths in [0, 1]
    rgb_weights: np.ndarray  # (3, n): XYZ_TO_SRGB @ xyz(l) * D65(l) * quadrature weight
    white: np.ndarray      # (3,) XYZ of the unit reflectance, Y = 1


@lru_cache(maxsize=1)
def quadrature() -> Quadrature:
    """Composite Simpson 3/8 over 360..830 nm on ``94 * SUBSTEPS + 1`` points."""
    n = (spectral.CIE_SAMPLES - 1) * SUBSTEPS + 1
    span = spectral.LAMBDA_MAX - spectral.LAMBDA_MIN
    lam = spectral.LAMBDA_MIN + np.arange(n) * (span / (n - 1))
    w = np.full(n, 3.0)
    w[3:-1:3] = 2.0
    w[[0, -1]] = 1.0
    w *= 3.0 / 8.0 * span / (n - 1)
    xyz = spectral.cie_xyz(lam) * (spectral.d65(lam) * w)[:, None]
    white = xyz.sum(axis=0)
    xyz /= white[1]
    return Quadrature((lam - spectral.LAMBDA_MIN) / span, spectral.XYZ_TO_SRGB @ xyz.T,
                      white / white[1])


def reflectance_rgb(s: np.ndarray) -> np.ndarray:
    """Linear sRGB under D65 of reflectances sampled at ``quadrature().t``, (..., n) -> (..., 3).
    This is the colour the fit matches; the tests use it for the round trip."""
    return s @ quadrature().rgb_weights.T


def _lab(rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CIELAB of linear sRGB (white = quadrature().white) and its Jacobian d lab / d rgb."""
    ratio = rgb @ SRGB_TO_XYZ.T / quadrature().white
    cube = ratio > _LAB_DELTA ** 3
    safe = np.where(cube, ratio, 1.0)
    f = np.where(cube, np.cbrt(safe), ratio / (3 * _LAB_DELTA ** 2) + 4.0 / 29.0)
    df = np.where(cube, 1.0 / (3.0 * np.cbrt(safe) ** 2), 1.0 / (3 * _LAB_DELTA ** 2))
    lab = f @ _LAB_ROWS.T + np.array([-16.0, 0.0, 0.0])
    d_ratio = _LAB_ROWS * df[..., None, :]                       # (..., 3 lab, 3 xyz)
    return lab, d_ratio @ (SRGB_TO_XYZ / quadrature().white[:, None])


def _sigmoid(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = 1.0 / np.sqrt(1.0 + x * x)
    return 0.5 + 0.5 * x * r, 0.5 * r ** 3


def _evaluate(coeffs: np.ndarray, target_lab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lab residual ``target - lab(coeffs)`` (N, 3) and the Jacobian d lab / d coeffs."""
    q = quadrature()
    powers = np.stack([q.t ** 2, q.t, np.ones_like(q.t)])        # (3, n)
    s, ds = _sigmoid(coeffs @ powers)
    lab, dlab = _lab(reflectance_rgb(s))
    drgb = (ds[:, None, :] * powers) @ q.rgb_weights.T           # (N, 3 coeff, 3 rgb)
    return target_lab - lab, dlab @ drgb.transpose(0, 2, 1)


def _fit(target_lab: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt on a batch: coefficients (N, 3) in normalised wavelength.

    Each cell keeps its own damping: a step that lowers the squared Lab residual is taken and
    the damping relaxed towards Gauss-Newton, otherwise the step is retried more damped. A
    cell stops once its residual is below ``TOLERANCE`` or no damping helps (the colour is
    as close as the model gets, e.g. white, whose sRGB chromaticity is a hair outside what a
    reflectance under the tabulated D65 reaches).
    """
    coeffs = coeffs.copy()
    residual, jac = _evaluate(coeffs, target_lab)
    cost = np.sum(residual ** 2, axis=1)
    damping = np.full(coeffs.shape[0], INITIAL_DAMPING)
    eye = np.eye(3)
    for _ in range(MAX_ITERATIONS):
        live = np.flatnonzero((cost >= TOLERANCE) & (damping < MAX_DAMPING))
        if live.size == 0:
            break
        j = jac[live]
        normal = j.transpose(0, 2, 1) @ j
        scaled = np.diagonal(normal, axis1=1, axis2=2)[..., None] * eye + 1e-12 * eye
        gradient = (j.transpose(0, 2, 1) @ residual[live][..., None])[..., 0]
        step = np.linalg.solve(normal + damping[live, None, None] * scaled,
                               gradient[..., None])[..., 0]
        trial = coeffs[live] + step
        trial_residual, trial_jac = _evaluate(trial, target_lab[live])
        trial_cost = np.sum(trial_residual ** 2, axis=1)
        better = trial_cost < cost[live]
        won, lost = live[better], live[~better]
        coeffs[won], residual[won], jac[won] = trial[better], trial_residual[better], \
            trial_jac[better]
        cost[won] = trial_cost[better]
        damping[won] = np.maximum(damping[won] / 3.0, MIN_DAMPING)
        damping[lost] *= 4.0
    return coeffs


def to_nanometres(coeffs: np.ndarray) -> np.ndarray:
    """Re-expand ``c0 t^2 + c1 t + c2`` with ``t = (l - 360) / 470`` as a polynomial in l."""
    a, b, c = coeffs[..., 0], coeffs[..., 1], coeffs[..., 2]
    lo, k = spectral.LAMBDA_MIN, 1.0 / (spectral.LAMBDA_MAX - spectral.LAMBDA_MIN)
    return np.stack([a * k * k, b * k - 2 * a * lo * k * k, c - b * lo * k + a * (lo * k) ** 2],
                    axis=-1)


def scale_axis(res: int) -> np.ndarray:
    """The brightness axis, ``smoothstep(smoothstep(k / (res - 1)))`` as float32."""
    def smoothstep(x: np.ndarray) -> np.ndarray:
        return x * x * (3.0 - 2.0 * x)
    return smoothstep(smoothstep(np.arange(res) / (res - 1))).astype(np.float32)


def optimize(res: int, progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The table: ``scale`` (res,) and ``data`` (3, res, res, res, 3), both float32."""
    scale = scale_axis(res)
    data = np.zeros((3, res, res, res, 3), dtype=np.float32)
    m, j, i = (a.ravel() for a in np.meshgrid(np.arange(3), np.arange(res), np.arange(res),
                                               indexing="ij"))
    x, y = i / (res - 1), j / (res - 1)
    start = res // 5
    order = list(range(start, res)) + list(range(start, -1, -1))
    coeffs = np.zeros((m.size, 3))
    began = time.monotonic()
    for step, k in enumerate(order):
        if k == start:
            coeffs[:] = 0.0
        b = float(scale[k])
        rgb = np.empty((m.size, 3))
        rgb[np.arange(m.size), m] = b
        rgb[np.arange(m.size), (m + 1) % 3] = x * b
        rgb[np.arange(m.size), (m + 2) % 3] = y * b
        coeffs = _fit(_lab(rgb)[0], coeffs)
        data[m, k, j, i] = to_nanometres(coeffs)
        if progress:
            done = step + 1
            print(f"\r  rgb2spec res {res}: {done}/{len(order)} scale steps "
                  f"({time.monotonic() - began:.0f} s)", end="", file=sys.stderr, flush=True)
    if progress:
        print(file=sys.stderr)
    return scale, data


def main(argv: list[str] | None = None) -> int:
    """Command line: ``--res N --out PATH`` writes ``scale`` and ``data`` to a .npz."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--res", type=int, default=64, help="cells per axis (default 64)")
    parser.add_argument("--out", type=Path, default=spectral.RGB2SPEC_TABLE)
    args = parser.parse_args(argv)
    if args.res < 3:
        parser.error("--res must be at least 3")
    scale, data = optimize(args.res, progress=True)
    np.savez_compressed(args.out, scale=scale, data=data)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
