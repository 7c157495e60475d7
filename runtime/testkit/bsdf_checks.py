"""The checks of a BSDF plugin, each a list of table rows (runtime/testkit/report.py):

1. chi-square: sample() against pdf() at several incident angles (Pearson, bins in
   (cos theta, phi) over the sphere, expected counts integrated from pdf(), one cell per
   Dirac lobe with the probability its samples report, one for the invalid samples);
2. sample() agrees with eval() and pdf(): pdf == pdf(wo), weight == eval(wo) / pdf(wo);
3. reciprocity of reflection: eval(wi, wo) / cos(wo) == eval(wo, wi) / cos(wi);
4. energy: the albedo (mean of weight * eta^2, the flux a sample carries) <= 1 per angle;
5. no NaN, Inf or negative value at grazing angles and extreme parameters.

Values are intensities (the [0][0] entry of the Mueller matrix in polarized variants).
A BSDF whose samples are all Dirac (a smooth conductor, a dielectric) has eval() and pdf()
zero: its chi-square tests the lobes' frequencies alone, and 2 and 3 do not apply.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .chi2 import PdfError, chi2_directions
from .common import GRAZING, Options, finite_rows, rng, sphere_sweep, surface, tile, wi_at
from .harness import Harness
from .report import SKIP, Row, verdict

f32 = np.float32
THETAS = (0.3, 1.0, 1.45)                  # incident angles; 1.45 rad = 83 degrees
INSIDE = (np.pi - 0.3, np.pi - 1.0)        # from below, when the BSDF answers there
MAX_LOBES = 8                              # distinct Dirac directions resolved per angle
RTOL_PDF, RTOL_WEIGHT, RTOL_RECIPROCAL = 1e-3, 1e-4, 1e-3
# stdlib models that are not reciprocal by design (Mitsuba 3 flags them NonSymmetric)
NOT_RECIPROCAL = {
    "hair": "Chiang et al.'s fiber model is not reciprocal: the offset h across the fiber "
            "comes from wi, and the scales tilt wi alone",
}


@dataclass(frozen=True)
class Traits:
    """What a first look at the samples found: all Dirac, some Dirac, transmission, an
    answer for light from below the surface."""

    all_delta: bool
    some_delta: bool
    transmits: bool
    below: bool

    def angles(self) -> tuple[float, ...]:
        return THETAS + (INSIDE if self.below else ())


def _sample(h: Harness, wi: np.ndarray, n: int, key: Any, params: dict) -> dict:
    gen = rng("bsdf", h.name, *key)
    bs = h.sample(surface(tile(wi, n)), gen.random(n).astype(f32),
                  gen.random((n, 2)).astype(f32), **params)
    bs["weight"] = np.asarray(bs["weight"]).reshape(n, -1)
    return bs


def probe(h: Harness, params: dict) -> Traits:
    """Traits from 4096 samples at each angle (above and below)."""
    delta = valid = 0
    transmits = below = False
    for theta in THETAS + INSIDE:
        wi = wi_at(theta)
        bs = _sample(h, wi, 4096, ("probe", theta), params)
        ok = bs["pdf"] > 0
        delta += int(np.sum(ok & bs["delta"]))
        valid += int(ok.sum())
        transmits |= bool(np.any(ok & (bs["wo"][:, 2] * wi[2] < 0)))
        below |= bool(wi[2] < 0 and np.any(ok))
    return Traits(valid > 0 and delta == valid, delta > 0, transmits, below)


def _lobes(bs: dict, delta: np.ndarray) -> tuple[list[float], list[float]] | None:
    """(counts, probabilities) of the Dirac lobes: the distinct directions of the Dirac
    samples, each with the probability its samples report; None if they do not resolve
    into a few lobes of one probability each (a dispersive lobe, say)."""
    if not delta.any():
        return [], []
    dirs, inverse = np.unique(bs["wo"][delta], axis=0, return_inverse=True)
    if len(dirs) > MAX_LOBES:
        return None
    counts, probs = [], []
    pdf = bs["pdf"][delta]
    for k in range(len(dirs)):
        p = pdf[inverse.ravel() == k]
        if np.ptp(p) > 1e-4 * p.max():
            return None
        counts.append(float(len(p)))
        probs.append(float(p[0]))
    return counts, probs


def _pdf_of(h: Harness, wi: np.ndarray, params: dict):
    return lambda d: np.asarray(h.pdf(surface(tile(wi, len(d))), np.ascontiguousarray(d, f32),
                                      **params), np.float64)


def chi2_and_energy(h: Harness, traits: Traits, opts: Options) -> list[Row]:
    """The chi-square and energy rows of each incident angle (one batch of samples each)."""
    chi2_rows, energy_rows = [], []
    n = opts.samples
    for theta in traits.angles():
        wi, case = wi_at(theta), f"theta {theta:.2f}"
        bs = _sample(h, wi, n, ("chi2", theta), opts.params)
        valid = bs["pdf"] > 0
        delta = valid & bs["delta"]
        lobes = _lobes(bs, delta)
        if lobes is None:
            chi2_rows.append(Row("chi2 sample vs pdf", case, "-", f"p > {opts.p_min:g}", SKIP,
                                 f"the Dirac samples do not resolve into <= {MAX_LOBES} "
                                 "lobes of one probability each"))
        else:
            try:
                p = chi2_directions(bs["wo"], valid & ~delta, _pdf_of(h, wi, opts.params), n,
                                    delta_obs=lobes[0], delta_prob=lobes[1], res=(60, 40))
                note = "" if p > opts.p_min else \
                    "sample() does not draw directions with the density pdf() gives them"
            except PdfError as e:
                p, note = 0.0, str(e)
            chi2_rows.append(Row("chi2 sample vs pdf", case, f"p = {p:.3g}",
                                 f"p > {opts.p_min:g}", verdict(p > opts.p_min), note))
        w = bs["weight"].astype(np.float64) * bs["eta"][:, None].astype(np.float64) ** 2
        a, s = w.mean(0), w.std(0) / np.sqrt(n)
        k = int(np.argmax(a - 4 * s))
        limit = 1 + 4 * s[k] + 1e-4
        ok = bool(np.all(np.isfinite(a))) and a[k] <= limit
        energy_rows.append(Row("energy (albedo <= 1)", case, f"albedo = {a[k]:.4f}",
                               f"<= {limit:.4f}", verdict(ok),
                               "" if ok else "the BSDF reflects more energy than it receives"))
    return chi2_rows + energy_rows


def consistency(h: Harness, traits: Traits, opts: Options) -> list[Row]:
    """pdf == pdf() and weight == eval() / pdf() for the non-Dirac samples."""
    if traits.all_delta:
        why = "every sample is Dirac: eval() and pdf() are 0"
        return [Row("pdf == pdf()", "all angles", "-", "-", SKIP, why),
                Row("weight == eval/pdf", "all angles", "-", "-", SKIP, why)]
    worst = {"pdf": (0.0, ""), "weight": (0.0, "")}
    zero_pdf_weight = ""
    n = 4000
    for theta in (0.0, 0.5, 1.2, 1.5) + (INSIDE if traits.below else ()):
        wi = wi_at(theta)
        bs = _sample(h, wi, n, ("consistency", theta), opts.params)
        ok = (bs["pdf"] > 0) & ~bs["delta"]
        if np.any(bs["weight"][~(bs["pdf"] > 0)] != 0) and not zero_pdf_weight:
            zero_pdf_weight = f"theta {theta:.2f}: a sample with pdf 0 has a weight"
        si = surface(tile(wi, n))
        ev = np.asarray(h.eval(si, bs["wo"], **opts.params), np.float64).reshape(n, -1)[ok]
        pd = np.asarray(h.pdf(si, bs["wo"], **opts.params), np.float64)[ok]
        with np.errstate(divide="ignore", invalid="ignore"):
            e_pdf = np.abs(pd - bs["pdf"][ok]) / np.abs(bs["pdf"][ok])
            ratio = ev / pd[:, None]
            e_w = np.abs(bs["weight"][ok] - ratio) / np.maximum(np.abs(ratio), 1e-3)
        for key, err in (("pdf", e_pdf), ("weight", e_w)):
            err = np.where(np.isnan(err), np.inf, err)
            if err.size and err.max() > worst[key][0]:
                worst[key] = (float(err.max()), f"theta {theta:.2f}")
    rows = []
    for key, name, tol in (("pdf", "pdf == pdf()", RTOL_PDF),
                           ("weight", "weight == eval/pdf", RTOL_WEIGHT)):
        err, where = worst[key]
        ok = err <= tol and not (key == "weight" and zero_pdf_weight)
        note = "" if ok else (zero_pdf_weight if err <= tol else
                              f"worst at {where}: sample() disagrees with "
                              + ("pdf()" if key == "pdf" else "eval() / pdf()"))
        rows.append(Row(name, "worst angle", f"rel. err {err:.2g}", f"<= {tol:g}",
                        verdict(ok), note))
    return rows


def reciprocity(h: Harness, traits: Traits, opts: Options) -> list[Row]:
    """f(wi, wo) == f(wo, wi) for pairs of directions above the surface (reflection)."""
    name, case = "reciprocity", "reflection"
    if traits.all_delta:
        return [Row(name, case, "-", "-", SKIP, "every sample is Dirac: eval() is 0")]
    if h.name in NOT_RECIPROCAL:
        return [Row(name, case, "-", "-", SKIP, NOT_RECIPROCAL[h.name])]
    n = 4000
    gen = rng("reciprocity", h.name)
    # cos >= 0.05: the cosines divided out below amplify rounding at grazing angles
    a, b = (np.stack([np.sqrt(1 - c * c) * np.cos(p), np.sqrt(1 - c * c) * np.sin(p), c],
                     -1).astype(f32)
            for c, p in ((gen.uniform(0.05, 1, n), gen.uniform(0, 2 * np.pi, n))
                         for _ in range(2)))
    fab = np.asarray(h.eval(surface(a), b, **opts.params), np.float64).reshape(n, -1)
    fba = np.asarray(h.eval(surface(b), a, **opts.params), np.float64).reshape(n, -1)
    fab /= b[:, 2:].astype(np.float64)
    fba /= a[:, 2:].astype(np.float64)
    scale = max(float(np.abs(fab).max()), float(np.abs(fba).max()))
    if not scale > 0:
        return [Row(name, case, "-", "-", SKIP, "eval() is 0 for every reflection")]
    err = float(np.max(np.abs(fab - fba) / np.maximum(np.abs(fab), 1e-3 * scale)))
    ok = err <= RTOL_RECIPROCAL
    return [Row(name, case, f"rel. err {err:.2g}", f"<= {RTOL_RECIPROCAL:g}", verdict(ok),
                "" if ok else "eval(wi, wo) / cos(wo) != eval(wo, wi) / cos(wi)")]


def _bad_values(h: Harness, params: dict, theta: float, wo: np.ndarray) -> str:
    """What is NaN, infinite or negative at this angle, or ''."""
    n = len(wo)
    si = surface(tile(wi_at(theta), n))
    outputs = {"eval": np.asarray(h.eval(si, wo, **params)),
               "pdf": np.asarray(h.pdf(si, wo, **params))}
    gen = rng("finite", h.name, theta)
    bs = h.sample(si, gen.random(n).astype(f32), gen.random((n, 2)).astype(f32), **params)
    outputs.update({f"sample.{k}": np.asarray(bs[k]) for k in ("wo", "pdf", "weight", "eta")})
    if h.polarized:
        outputs["eval (Mueller)"] = h.eval(si, wo, mueller=True, **params)
        outputs["sample.weight (Mueller)"] = bs["mueller"]
    for key, v in outputs.items():
        if not np.all(np.isfinite(v)):
            return f"{key} is NaN or infinite"
        if key in ("eval", "pdf", "sample.pdf", "sample.weight") and np.any(v < 0):
            return f"{key} is negative"
    return ""


def finite(h: Harness, opts: Options) -> list[Row]:
    """No NaN, Inf or negative value at grazing angles, for the given parameters and with
    each parameter in turn at an extreme value."""
    wo = sphere_sweep(512, h.name)

    def bad(params: dict) -> str:
        for theta in GRAZING:
            why = _bad_values(h, params, theta, wo)
            if why:
                return f"{why} at theta {theta:.4g}"
        return ""
    return finite_rows(h.decl, opts, bad, f"{len(GRAZING)} grazing angles")


def check_bsdf(h: Harness, opts: Options) -> list[Row]:
    """Every check of the BSDF ``h``, as table rows."""
    traits = probe(h, opts.params)
    return (chi2_and_energy(h, traits, opts) + consistency(h, traits, opts)
            + reciprocity(h, traits, opts) + finite(h, opts))
