"""Pearson's chi-square test of sampled directions against a pdf, as Mitsuba's ChiSquareTest:
bins in (cos theta, phi), expected counts integrated from the pdf by adaptive Gauss-Legendre
quadrature, sparse bins pooled; the p-value from the regularized incomplete gamma function.

numpy only (no scipy): ``rdsl test-plugin`` needs the p-value at run time, and the runtime's
dependencies stay what rendering needs; :func:`chi2_sf` is checked against scipy in the
tests.  Also Smith's G1 of Beckmann, exact and as fitted (the stdlib's microfacet tests).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

f32 = np.float32
Pdf = Callable[[np.ndarray], np.ndarray]  # (n, 3) float32 directions -> (n,) densities

_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)
_EPS = 1e-15


class PdfError(ValueError):
    """pdf() is not a density: NaN, negative, or it integrates to more than 1."""


def _gamma_series(a: float, x: float) -> float:
    """The regularized lower incomplete gamma P(a, x) by its power series (x < a + 1)."""
    term = total = 1.0 / a
    ap = a
    for _ in range(10_000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_fraction(a: float, x: float) -> float:
    """The regularized upper incomplete gamma Q(a, x) by Lentz's continued fraction
    (x >= a + 1; Numerical Recipes' gcf)."""
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return math.exp(-x + a * math.log(x) - math.lgamma(a)) * h


def chi2_sf(stat: float, dof: int) -> float:
    """P(X >= stat) for X chi-square distributed with ``dof`` degrees of freedom:
    Q(dof / 2, stat / 2), the regularized upper incomplete gamma function."""
    if dof <= 0:
        raise ValueError(f"degrees of freedom must be positive, not {dof}")
    if not stat > 0:
        return 1.0
    a, x = 0.5 * dof, 0.5 * stat
    if x < a + 1.0:
        return max(0.0, 1.0 - _gamma_series(a, x))
    return min(1.0, _gamma_fraction(a, x))


def _gl_rects(pdf: Pdf, rects: np.ndarray) -> np.ndarray:
    """5 x 5 Gauss-Legendre integral of pdf over (cos theta, phi) rectangles (M, 4)."""
    c0, c1, p0, p1 = rects.T
    hc, hp = 0.5 * (c1 - c0), 0.5 * (p1 - p0)
    cs = (0.5 * (c0 + c1))[:, None] + hc[:, None] * _GL_X[None, :]          # (M, 5)
    ps = (0.5 * (p0 + p1))[:, None] + hp[:, None] * _GL_X[None, :]
    C = np.broadcast_to(cs[:, :, None], (len(rects), 5, 5))
    P = np.broadcast_to(ps[:, None, :], (len(rects), 5, 5))
    st = np.sqrt(np.maximum(1 - C * C, 0))
    d = np.stack([st * np.cos(P), st * np.sin(P), C], -1).reshape(-1, 3).astype(f32)
    v = np.asarray(pdf(d), np.float64).reshape(len(rects), 5, 5)
    if not (np.all(np.isfinite(v)) and np.all(v >= 0)):
        raise PdfError("pdf() is NaN, infinite or negative for some directions")
    return np.einsum("mij,i,j->m", v, _GL_W, _GL_W) * hc * hp


def _split(rects: np.ndarray) -> np.ndarray:
    c0, c1, p0, p1 = rects.T
    cm, pm = 0.5 * (c0 + c1), 0.5 * (p0 + p1)
    kids = [np.stack(r, -1) for r in ((c0, cm, p0, pm), (cm, c1, p0, pm),
                                      (c0, cm, pm, p1), (cm, c1, pm, p1))]
    return np.stack(kids, 1).reshape(-1, 4)


def integrate_bins(pdf: Pdf, cos_edges: np.ndarray, phi_edges: np.ndarray, n: int,
                   max_depth: int = 7) -> np.ndarray:
    """Probability of each (cos theta, phi) bin: adaptive (2x2-split) Gauss-Legendre
    quadrature until the estimate moves by < 0.05 sqrt(p / n), i.e. well below the sampling
    noise of n samples."""
    C0, P0 = np.meshgrid(cos_edges[:-1], phi_edges[:-1], indexing="ij")
    C1, P1 = np.meshgrid(cos_edges[1:], phi_edges[1:], indexing="ij")
    rects = np.stack([C0.ravel(), C1.ravel(), P0.ravel(), P1.ravel()], -1)
    owner = np.arange(len(rects))
    out = np.zeros(len(rects))
    coarse = _gl_rects(pdf, rects)
    for depth in range(max_depth + 1):
        kids = _split(rects)
        fine4 = _gl_rects(pdf, kids).reshape(-1, 4)
        fine = fine4.sum(1)
        tol = 0.05 * np.sqrt(np.maximum(fine, 1.0 / n) / n) * 4.0 ** -depth
        done = (np.abs(fine - coarse) <= tol) | (depth == max_depth)
        np.add.at(out, owner[done], fine[done])
        keep = ~done
        rects = kids.reshape(-1, 4, 4)[keep].reshape(-1, 4)
        coarse = fine4[keep].ravel()
        owner = np.repeat(owner[keep], 4)
        if len(rects) == 0:
            break
    return out.reshape(len(cos_edges) - 1, len(phi_edges) - 1)


def chi2_pvalue(observed: np.ndarray, expected: np.ndarray,
                min_expected: float = 5.0) -> float:
    """Pearson's chi-square p-value, the cells with expected < min_expected pooled.  Samples
    in a cell of expected count 0 give p = 0 (something was sampled that cannot happen)."""
    observed, expected = np.ravel(observed), np.ravel(expected)
    sparse = expected < min_expected
    obs = np.append(observed[~sparse], observed[sparse].sum())
    exp = np.append(expected[~sparse], expected[sparse].sum())
    keep = exp > 0
    if np.any(obs[~keep] != 0):
        return 0.0
    if keep.sum() < 2:
        return 1.0
    stat = float(np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep]))
    return chi2_sf(stat, int(keep.sum()) - 1)


def chi2_directions(wo: np.ndarray, valid: np.ndarray, pdf: Pdf, n: int,
                    delta_obs: Sequence[float] = (), delta_prob: Sequence[float] = (),
                    res: tuple[int, int] = (40, 40), lower: bool = True) -> float:
    """p-value of the valid sampled directions (and the discrete lobes: their counts and
    probabilities) against pdf(); one more cell holds the invalid samples, expected
    1 - (the integral of pdf + the lobes' probabilities).  Raises :class:`PdfError` when
    pdf() integrates to more than 1."""
    cos_edges = np.linspace(-1 if lower else 0, 1, res[0] + 1)
    phi_edges = np.linspace(-np.pi, np.pi, res[1] + 1)
    d = wo[valid].astype(np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    obs, _, _ = np.histogram2d(np.clip(d[:, 2], -1, 1), np.arctan2(d[:, 1], d[:, 0]),
                               bins=[cos_edges, phi_edges])
    exp = n * integrate_bins(pdf, cos_edges, phi_edges, n)
    rest = n - exp.sum() - n * sum(delta_prob)
    if rest < -1e-3 * n:
        raise PdfError(f"pdf() integrates to more than 1 ({exp.sum() / n:.4f}"
                       + (f", plus {sum(delta_prob):.4f} in discrete lobes)" if delta_prob
                          else ")"))
    observed = np.concatenate([obs.ravel(), list(delta_obs),
                               [n - valid.sum() - sum(delta_obs)]])
    expected = np.concatenate([exp.ravel(), n * np.asarray(delta_prob, float), [max(rest, 0)]])
    return chi2_pvalue(observed, expected)


def beckmann_g1_exact(wi: np.ndarray, alpha: float) -> float:
    """Smith's G1 of the Beckmann distribution, exact (erf), for m = the normal."""
    ct = abs(float(wi[2]))
    a = ct / (alpha * math.sqrt(1 - ct * ct))
    return 2 / (1 + math.erf(a) + math.exp(-a * a) / (a * math.sqrt(math.pi)))


def beckmann_g1_fit(wi: np.ndarray, alpha: float) -> float:
    """The rational fit of Walter et al. 2007 that microfacet.rdsl (and Mitsuba) use."""
    ct = abs(float(wi[2]))
    a = ct / (alpha * math.sqrt(1 - ct * ct))
    return 1.0 if a >= 1.6 else min((3.535 * a + 2.181 * a * a)
                                    / (1 + 2.276 * a + 2.577 * a * a), 1.0)
