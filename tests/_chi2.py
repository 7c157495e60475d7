"""Pearson's chi-square test of sampled directions against a pdf, as Mitsuba's ChiSquareTest:
bins in (cos theta, phi), expected counts integrated from the pdf by adaptive Gauss-Legendre
quadrature, sparse bins pooled; and Smith's G1 of Beckmann, exact and as fitted."""

from __future__ import annotations

import numpy as np
from scipy import stats

f32 = np.float32


_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


def _gl_rects(pdf, rects):
    """5 x 5 Gauss-Legendre integral of pdf over (cos theta, phi) rectangles (M, 4)."""
    c0, c1, p0, p1 = rects.T
    hc, hp = 0.5 * (c1 - c0), 0.5 * (p1 - p0)
    cs = (0.5 * (c0 + c1))[:, None] + hc[:, None] * _GL_X[None, :]          # (M, 5)
    ps = (0.5 * (p0 + p1))[:, None] + hp[:, None] * _GL_X[None, :]
    C = np.broadcast_to(cs[:, :, None], (len(rects), 5, 5))
    P = np.broadcast_to(ps[:, None, :], (len(rects), 5, 5))
    st = np.sqrt(np.maximum(1 - C * C, 0))
    d = np.stack([st * np.cos(P), st * np.sin(P), C], -1).reshape(-1, 3).astype(f32)
    v = pdf(d).reshape(len(rects), 5, 5)
    assert np.all(np.isfinite(v)) and np.all(v >= 0)
    return np.einsum("mij,i,j->m", v, _GL_W, _GL_W) * hc * hp


def _split(rects):
    c0, c1, p0, p1 = rects.T
    cm, pm = 0.5 * (c0 + c1), 0.5 * (p0 + p1)
    kids = [np.stack(r, -1) for r in ((c0, cm, p0, pm), (cm, c1, p0, pm),
                                      (c0, cm, pm, p1), (cm, c1, pm, p1))]
    return np.stack(kids, 1).reshape(-1, 4)


def integrate_bins(pdf, cos_edges, phi_edges, n, max_depth=7):
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


def chi2_pvalue(observed, expected, min_expected=5.0):
    """Pearson's chi-square p-value, the cells with expected < min_expected pooled."""
    observed, expected = np.ravel(observed), np.ravel(expected)
    sparse = expected < min_expected
    obs = np.append(observed[~sparse], observed[sparse].sum())
    exp = np.append(expected[~sparse], expected[sparse].sum())
    keep = exp > 0
    assert np.all(obs[~keep] == 0), "samples where pdf() is 0"
    if keep.sum() < 2:
        return 1.0
    stat = float(np.sum((obs[keep] - exp[keep]) ** 2 / exp[keep]))
    return float(stats.chi2.sf(stat, int(keep.sum()) - 1))


def chi2_directions(wo, valid, pdf, n, delta_obs=(), delta_prob=(), res=(40, 40),
                    lower=True):
    """p-value of the valid sampled directions (and the discrete lobes) against pdf()."""
    cos_edges = np.linspace(-1 if lower else 0, 1, res[0] + 1)
    phi_edges = np.linspace(-np.pi, np.pi, res[1] + 1)
    d = wo[valid].astype(np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    obs, _, _ = np.histogram2d(np.clip(d[:, 2], -1, 1), np.arctan2(d[:, 1], d[:, 0]),
                               bins=[cos_edges, phi_edges])
    exp = n * integrate_bins(pdf, cos_edges, phi_edges, n)
    rest = n - exp.sum() - n * sum(delta_prob)
    assert rest > -1e-3 * n, f"pdf() integrates to more than 1 ({exp.sum() / n:.4f})"
    observed = np.concatenate([obs.ravel(), list(delta_obs), [n - valid.sum() - sum(delta_obs)]])
    expected = np.concatenate([exp.ravel(), n * np.asarray(delta_prob, float), [max(rest, 0)]])
    return chi2_pvalue(observed, expected)


def beckmann_g1_exact(wi, alpha):
    """Smith's G1 of the Beckmann distribution, exact (erf), for m = the normal."""
    from scipy.special import erf
    ct = abs(float(wi[2]))
    a = ct / (alpha * np.sqrt(1 - ct * ct))
    return 2 / (1 + erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))


def beckmann_g1_fit(wi, alpha):
    """The rational fit of Walter et al. 2007 that microfacet.rdsl (and Mitsuba) use."""
    ct = abs(float(wi[2]))
    a = ct / (alpha * np.sqrt(1 - ct * ct))
    return 1.0 if a >= 1.6 else min((3.535 * a + 2.181 * a * a)
                                    / (1 + 2.276 * a + 2.577 * a * a), 1.0)
