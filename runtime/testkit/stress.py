"""``rdsl stress``: every stdlib BSDF, emitter and texture (or the plugins of the files given)
swept over its whole domain in each variant, and one table row per plugin and variant that
counts what went wrong.

The sweep (a *case* is one parameter set at one incident direction):

* incident directions with cos theta = 1, 0.5, 1e-3, 1e-5, 1e-7, exactly 0, and below the
  horizon (-1e-7, -0.5); outgoing directions over the sphere with the poles and exactly
  tangent ones (:func:`common.sphere_sweep`), emitters and textures over uv in and far outside
  the unit square;
* each parameter in turn, the others at their defaults: roughness (``alpha``, ``alpha_v``,
  ``roughness``) 1e-4 .. 1; an index of refraction (``*ior``, ``eta``) 1.0001 .. 4 and 0.5;
  colours (Textures) 0 and 1; an emitter's radiance 0 and 1e30; weights in [0, 1] at 0 and
  1; booleans flipped; ``distribution`` 0 and 1; and every roughness with every IOR.

Counted per plugin and variant: NaN and Inf among the outputs (eval, pdf, the sample's wo,
pdf, weight and eta; an emitter's radiance; a texture's eval and eval_1), negative values
(eval, pdf, weights, radiance, texture values), energy gain (cases whose Monte Carlo albedo
from sample(), the mean of weight * eta^2 as :mod:`bsdf_checks` computes it, exceeds
``1 + ENERGY_TOL + 4`` standard errors; ``ENERGY_TOL_PLUGIN`` for the stdlib models that are
not energy conserving by design, from the albedo of Mitsuba 3's plugin), and mismatches (non-Dirac samples whose pdf differs
from pdf() by more than ``RTOL_PDF`` or whose weight differs from eval()/pdf() by more than
``RTOL_WEIGHT``, the tolerances of ``rdsl test-plugin``, plus what the float32 rounding of the
sampled direction moves pdf() and eval()/pdf() by: :func:`float32_allowance`).

NaN and +Inf *parameters* (what a scene could hold) are a separate column and do not fail the
run: the expected behaviour is that they propagate (the output is NaN or Inf, which the
renderer's film counts and reports) or are absorbed into a finite, non-negative value; the
column counts the cases whose output was finite and *negative* ("silent garbage"), which does
fail.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .bsdf_checks import RTOL_PDF, RTOL_WEIGHT
from .common import rng, sphere_sweep, surface, tile
from .harness import KINDS, STDLIB, Declaration, Harness, declarations
from .texture_checks import _uvs

f32 = np.float32
COS_WI = (1.0, 0.5, 1e-3, 1e-5, 1e-7, 0.0, -1e-7, -0.5)
ENERGY_TOL = 1e-3
# stdlib models that are not energy conserving by design, with the energy tolerance that
# Mitsuba 3's own plugin needs over this sweep (its albedo measured at the same inputs,
# llvm_ad_rgb, 2^18 samples per case, the mean of the sample weights):
ENERGY_TOL_PLUGIN = {
    # Disney's diffuse (its retro-reflection) and specular lobes are not jointly normalized:
    # Mitsuba's principled reflects 1.044 at normal incidence with base_color 1, 1.192 at
    # cos 1e-3, and at most 1.552 +- 0.037 (cos 1e-7, roughness 0.01, eta 0.5)
    "principled": 0.6,
    # the same diffuse lobe in the thin model: Mitsuba's principledthin reflects 1.0059 at
    # normal incidence with base_color 1, at most 1.0084 (cos 0.5, base_color 1)
    "principledthin": 0.01,
}
ROUGH = (1e-4, 1e-3, 1e-2, 0.1, 0.5, 1.0)
IOR = (1.0001, 1.33, 2.0, 4.0, 0.5)
FAST = {"rough": (1e-4, 0.1, 1.0), "ior": (1.0001, 4.0, 0.5), "samples": 4096, "wo": 256,
        "cos_wi": (1.0, 1e-7, 0.0, -0.5)}
# Cases where a float32 microfacet model cannot recover its half vector m from (wi, wo), so
# that no implementation can meet RTOL_PDF / RTOL_WEIGHT: their mismatches are not counted
# (the note says how many). Measured on Mitsuba 3's plugins (llvm_ad_rgb, GGX, 4096 samples,
# the same checks): near-Dirac lobes, roughconductor at alpha 1e-4 / 1e-3 / 1e-2 and cos
# theta_i 1e-3: 4069 / 3209 / 11 samples mismatch, roughdielectric 4078 / 3815 / 1257 (and
# 1119 at alpha 1e-4, cos 0.5); refraction with a relative IOR within 1e-3 of 1, where
# wi.m + eta wo.m cancels: roughdielectric at int_ior 1.0001, 905 at cos 0.5, 2465 at -0.5.
MICROFACET = ("roughconductor", "roughdielectric")


def mismatch_exempt(decl: Declaration, params: dict, cos_wi: float) -> str:
    """Why the mismatches of this case are not counted, or ''."""
    if decl.name not in MICROFACET or not decl.path.resolve().is_relative_to(STDLIB.resolve()):
        return ""
    value = {p.name: params.get(p.name, p.default) for p in decl.params}
    rough = min((float(v) for k, v in value.items() if _kind(k) == "rough" and float(v) >= 0),
                default=1.0)
    if rough <= 1e-4 and abs(cos_wi) < 1 or rough <= 1e-2 and abs(cos_wi) <= 1e-3:
        return "near-Dirac lobe"
    if {"int_ior", "ext_ior"} <= value.keys():
        if abs(float(value["int_ior"]) / float(value["ext_ior"]) - 1) < 1e-3:
            return "relative IOR ~ 1"
    return ""


SKIP_FILES = ("common", "blend_example")   # helpers and an example, not plugins to ship
# stdlib plugins the one-plugin harness cannot call meaningfully, and why
SKIP_PLUGINS = {"bitmap": "reads its texels from the scene's image buffer, which a one-plugin "
                          "harness does not hold (it would read past an empty buffer)"}


@dataclass
class Counts:
    """One table row: cases run and what each went wrong in (values, or cases for
    energy gain), and the NaN/Inf-parameter cases: run, propagated, silently negative."""

    cases: int = 0
    nan: int = 0
    inf: int = 0
    negative: int = 0
    energy_gain: int = 0
    mismatch: int = 0
    bad_param_cases: int = 0
    bad_param_propagated: int = 0
    bad_param_garbage: int = 0
    exempt: int = 0   # cases whose mismatches are not counted (mismatch_exempt)
    conditioned: int = 0   # samples within float32_allowance (not counted)
    notes: dict[str, str] = field(default_factory=dict)  # the first problem of each kind

    def failed(self) -> bool:
        return any((self.nan, self.inf, self.negative, self.energy_gain, self.mismatch,
                    self.bad_param_garbage))

    def note(self, kind: str, text: str) -> None:
        self.notes.setdefault(kind, text)


def _kind(name: str) -> str:
    n = name.lower()
    if n in ("alpha", "alpha_u", "alpha_v", "roughness"):
        return "rough"
    if n.endswith("ior") or n == "eta":
        return "ior"
    return ""


def _values(decl: Declaration, p: Any, fast: bool) -> list[Any]:
    """The values the sweep gives parameter ``p`` of ``decl`` (besides its default)."""
    kind = _kind(p.name)
    if kind and p.type in ("Float", "Spectrum"):
        return list(FAST[kind] if fast else ROUGH if kind == "rough" else IOR)
    if p.type == "Texture":
        return [0.0, 1e30] if decl.kind == "emitter" else [0.0, 1.0]
    if p.type == "Bool":
        return [not p.default]
    if p.type == "Int" and p.name == "distribution":
        return [0, 1]
    if p.type in ("Float", "Spectrum") and isinstance(p.default, (int, float)):
        d = float(p.default)
        if p.name == "k":
            return [0.0, 1e-4, 10.0]
        if 0 <= d <= 1:
            return [0.0, 1.0]
    return []


def param_sets(decl: Declaration, fast: bool) -> Iterator[dict[str, Any]]:
    """The defaults, each parameter at each of its values, then each roughness with each IOR."""
    yield {}
    for p in decl.params:
        for v in _values(decl, p, fast):
            if v != p.default:
                yield {p.name: v}
    rough = [p for p in decl.params if _kind(p.name) == "rough" and p.type == "Float"]
    ior = [p for p in decl.params if _kind(p.name) == "ior" and p.type in ("Float", "Spectrum")]
    for r in rough[:1]:
        for i in ior:
            for rv in _values(decl, r, fast):
                for iv in _values(decl, i, fast):
                    yield {r.name: rv, i.name: iv}


def bad_param_sets(decl: Declaration) -> Iterator[dict[str, Any]]:
    """Each number or colour parameter in turn at NaN and at +Inf."""
    for p in decl.params:
        if p.type in ("Float", "Spectrum", "Texture"):
            for v in (math.nan, math.inf):
                yield {p.name: v}


def _wi(c: float) -> np.ndarray:
    s = math.sqrt(max(0.0, 1.0 - c * c))
    return np.array([s * math.cos(0.4), s * math.sin(0.4), c], f32)


def _tally(c: Counts, values: dict[str, np.ndarray], signed: tuple[str, ...], where: str) -> None:
    """Add the NaN, Inf and negative values among ``values`` to ``c``."""
    for key, v in values.items():
        v = np.asarray(v, np.float64)
        nan, inf = int(np.isnan(v).sum()), int(np.isinf(v).sum())
        neg = int((v < 0).sum()) if key not in signed else 0
        c.nan, c.inf, c.negative = c.nan + nan, c.inf + inf, c.negative + neg
        if nan or inf or neg:
            c.note(key, f"{key}: {nan} NaN, {inf} Inf, {neg} < 0 at {where}")


def _bsdf_outputs(h: Harness, params: dict, cos_wi: float, n_wo: int,
                  n: int) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """(eval/pdf over the sweep, the samples, eval and pdf at the sampled directions)."""
    wo = sphere_sweep(n_wo, h.name)
    wi = _wi(cos_wi)
    swept = {"eval": h.eval(surface(tile(wi, n_wo)), wo, **params),
             "pdf": h.pdf(surface(tile(wi, n_wo)), wo, **params)}
    gen = rng("stress", h.name, cos_wi, repr(params))
    si = surface(tile(wi, n))
    bs = h.sample(si, gen.random(n).astype(f32), gen.random((n, 2)).astype(f32), **params)
    wo_s = np.ascontiguousarray(np.nan_to_num(bs["wo"]), f32)
    ev = np.asarray(h.eval(si, wo_s, **params), np.float64).reshape(n, -1)
    return swept, bs, ev, np.asarray(h.pdf(si, wo_s, **params), np.float64)


# The step (radians) of the finite differences that estimate how fast pdf() and eval()/pdf()
# turn with wo (float32_allowance): ~170 float32 ulps of a unit vector's component, so that the
# model's own float32 rounding noise (up to ~1e-3 relative where it cancels) adds under 1% of
# itself to the allowance and cannot hide a real disagreement; and small against the scale on
# which the microfacet models vary at the sweep's most grazing inputs (|wi + wo| ~ 3e-4).
FD_STEP = 1e-5


def _turned(wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """wo turned by +-FD_STEP along two tangents to it: (n, 4, 3), unit, float32; and the
    tangents (n, 2, 3)."""
    w = wo.astype(np.float64)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    a = np.where(np.abs(w[:, :1]) < 0.6, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(w, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t = np.stack([t1, np.cross(w, t1)], 1)
    out = w[:, None] + FD_STEP * np.concatenate([t, -t], 1)
    return (out / np.linalg.norm(out, axis=2, keepdims=True)).astype(f32), t


def float32_allowance(h: Harness, params: dict, wi: np.ndarray,
                      wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far (relative) pdf() and eval()/pdf() move when wo turns by the float32 rounding of
    its components, an ulp each (half from rounding wo, half from the operations before it):
    |d ln q / d wo| along two tangents, by central differences, times that turn. sample() gets
    its pdf and weight at the direction it constructs, and returns it rounded; near a
    singularity of the model (m = |wi + eta wo| where |wi + eta wo| ~ 1e-3) that rounding moves
    the pdf by more than RTOL_PDF even in float64 (tests/test_stress_findings.py). 0 where q
    vanishes on either side (an edge of the lobe, where no derivative bounds the change)."""
    n = len(wo)
    moved, t = _turned(wo)
    si = surface(tile(wi, 4 * n))
    flat = np.ascontiguousarray(moved.reshape(-1, 3))
    pdf = np.asarray(h.pdf(si, flat, **params), np.float64).reshape(n, 4)
    ev = np.asarray(h.eval(si, flat, **params), np.float64).reshape(n, 4, -1)
    turn = np.abs(t) @ np.spacing(np.abs(wo).astype(f32)).astype(np.float64)[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        d_pdf = np.abs(np.log(pdf[:, :2] / pdf[:, 2:])) / (2 * FD_STEP)
        ratio = ev / pdf[..., None]
        # relative to max(|eval / pdf|, 1e-3), as _mismatches measures the weight's error
        scale = np.maximum(np.abs(ratio[:, :2] + ratio[:, 2:]) / 2, 1e-3)
        d_w = np.abs(ratio[:, :2] - ratio[:, 2:]) / (2 * FD_STEP) / scale
    a_pdf = np.sum(d_pdf * turn[..., 0], 1)
    a_w = np.max(np.sum(d_w * turn, 1), 1)
    return (np.where(np.isfinite(a_pdf), a_pdf, 0.0), np.where(np.isfinite(a_w), a_w, 0.0))


def _mismatches(h: Harness, params: dict, wi: np.ndarray, bs: dict, ev: np.ndarray,
                pd: np.ndarray) -> tuple[int, str, int]:
    """Non-Dirac samples whose pdf or weight disagrees with pdf() or eval()/pdf() by more than
    the test kit's tolerances plus float32_allowance, and samples with pdf 0 that carry a
    weight; and how many disagree by less than the allowance (not counted)."""
    weight = np.asarray(bs["weight"], np.float64).reshape(len(pd), -1)
    spdf = np.asarray(bs["pdf"], np.float64)
    ok = (spdf > 0) & ~np.asarray(bs["delta"], bool) & np.all(np.isfinite(weight), 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        e_pdf = np.abs(pd[ok] - spdf[ok]) / spdf[ok]
        ratio = ev[ok] / pd[ok, None]
        e_w = np.max(np.abs(weight[ok] - ratio) / np.maximum(np.abs(ratio), 1e-3), 1)
    bad_pdf = ~(e_pdf <= RTOL_PDF)
    bad_w = ~(e_w <= RTOL_WEIGHT)
    near = bad_pdf | bad_w
    conditioned = 0
    if near.any():
        wo = np.ascontiguousarray(np.asarray(bs["wo"], f32)[ok][near])
        a_pdf, a_w = float32_allowance(h, params, wi, wo)
        bad_pdf[near] &= ~(e_pdf[near] <= RTOL_PDF + a_pdf)
        bad_w[near] &= ~(e_w[near] <= RTOL_WEIGHT + a_w)
        conditioned = int(near.sum() - np.sum(bad_pdf | bad_w))
    zero = int(np.sum(np.any(weight[~(spdf > 0)] != 0, 1)))
    count = int(np.sum(bad_pdf | bad_w)) + zero
    why = ""
    if count:
        worst = float(np.nanmax(np.where(np.isnan(e_w), np.inf, e_w), initial=0))
        why = (f"{int(bad_pdf.sum())} pdf != pdf(), {int(bad_w.sum())} weight != eval/pdf "
               f"(worst rel. err {worst:.3g}), {zero} weight with pdf 0")
    return count, why, conditioned


def energy_tol(decl: Declaration) -> float:
    """ENERGY_TOL, or the stdlib plugin's own (ENERGY_TOL_PLUGIN)."""
    stdlib = decl.path.resolve().is_relative_to(STDLIB.resolve())
    return ENERGY_TOL_PLUGIN.get(decl.name, ENERGY_TOL) if stdlib else ENERGY_TOL


def _albedo_gain(bs: dict, n: int, tol: float = ENERGY_TOL) -> tuple[bool, str]:
    w = np.asarray(bs["weight"], np.float64).reshape(n, -1)
    w = w * np.asarray(bs["eta"], np.float64)[:, None] ** 2
    w = np.where(np.isfinite(w), w, 0.0)
    a, s = w.mean(0), w.std(0) / math.sqrt(n)
    k = int(np.argmax(a - 4 * s))
    limit = 1 + tol + 4 * s[k]
    return a[k] > limit, f"albedo {a[k]:.4f} > {limit:.4f}"


def stress_bsdf(h: Harness, c: Counts, sets: list[dict], cos_wis: tuple, n_wo: int,
                n: int) -> None:
    """Every parameter set at every incident direction of a BSDF into ``c``."""
    for params in sets:
        for cos_wi in cos_wis:
            where = f"cos {cos_wi:g}, {_describe(params)}"
            swept, bs, ev, pd = _bsdf_outputs(h, params, cos_wi, n_wo, n)
            c.cases += 1
            outputs = {**{k: np.asarray(v) for k, v in swept.items()},
                       **{f"sample.{k}": bs[k] for k in ("wo", "pdf", "weight", "eta")}}
            _tally(c, outputs, ("sample.wo",), where)
            m, why, conditioned = _mismatches(h, params, _wi(cos_wi), bs, ev, pd)
            if conditioned:
                c.conditioned += conditioned
                c.note("conditioned", f"{conditioned} at {where}")
            exempt = mismatch_exempt(h.decl, params, cos_wi)
            if m and exempt:
                c.exempt += 1
                c.note("exempt", f"{exempt} at {where}")
                m = 0
            c.mismatch += m
            if m:
                c.note("mismatch", f"mismatch: {why} at {where}")
            gain, why = _albedo_gain(bs, n, energy_tol(h.decl))
            if gain:
                c.energy_gain += 1
                c.note("energy", f"energy gain: {why} at {where}")
    if c.conditioned:
        c.notes["conditioned"] = (f"{c.conditioned} sample(s) disagree by less than the float32 "
                                  f"rounding of wo allows (float32_allowance), the first: "
                                  f"{c.notes['conditioned']}")
    if c.exempt:
        c.notes["exempt"] = (f"mismatches not counted in {c.exempt} case(s) where float32 "
                             f"cannot recover m (MICROFACET), the first: {c.notes['exempt']}")


def _emitter_or_texture(h: Harness, params: dict, n: int) -> dict[str, np.ndarray]:
    if h.decl.kind == "emitter":
        wi = sphere_sweep(n, h.name)
        uv = rng("stress-uv", h.name).uniform(-0.5, 1.5, (n, 2)).astype(f32)
        return {"radiance": h.emitted(surface(wi, uv), **params)}
    uv = _uvs(h.name, n)
    si = surface(np.tile(np.array([0, 0, 1], f32), (len(uv), 1)), uv)
    out = {"eval": h.texture(si, **params)}
    if "eval_1" in h.decl.methods:
        out["eval_1"] = h.texture(si, one=True, **params)
    return out


def _describe(params: dict) -> str:
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
                     for k, v in params.items()) or "defaults"


def _bad_params(h: Harness, c: Counts, eval_all: Callable[[dict], dict]) -> None:
    """The NaN/Inf-parameter cases: propagated (non-finite out) or silently negative."""
    for params in bad_param_sets(h.decl):
        out = eval_all(params)
        c.bad_param_cases += 1
        vals = [np.asarray(v, np.float64) for k, v in out.items() if not k.endswith(".wo")]
        if any(not np.all(np.isfinite(v)) for v in vals):
            c.bad_param_propagated += 1
        finite_neg = any(np.any(np.isfinite(v) & (v < 0)) for v in vals)
        if finite_neg:
            c.bad_param_garbage += 1
            c.note("garbage", f"finite negative output with {_describe(params)}")


def stress_plugin(decl: Declaration, variant: str, fast: bool) -> Counts:
    """The counts of one plugin in one variant."""
    h = Harness(variant=variant, decl=decl)
    c = Counts()
    sets = list(param_sets(decl, fast))
    n_wo = FAST["wo"] if fast else 1024
    if decl.kind == "bsdf":
        n = FAST["samples"] if fast else 32768
        cos_wis = FAST["cos_wi"] if fast else COS_WI
        stress_bsdf(h, c, sets, cos_wis, n_wo, n)

        def eval_all(params: dict) -> dict:
            out = {}
            for cos_wi in cos_wis:
                swept, bs, _, _ = _bsdf_outputs(h, params, cos_wi, n_wo, n_wo)
                out.update({f"{cos_wi}.{k}": v for k, v in swept.items()})
                out.update({f"{cos_wi}.sample.{k}": bs[k] for k in ("wo", "pdf", "weight")})
            return out
    else:
        for params in sets:
            c.cases += 1
            _tally(c, _emitter_or_texture(h, params, n_wo), (), _describe(params))

        def eval_all(params: dict) -> dict:
            return _emitter_or_texture(h, params, n_wo)
    _bad_params(h, c, eval_all)
    return c


def stdlib_plugins() -> list[Declaration]:
    """Every BSDF, emitter and texture the stdlib declares (but SKIP_PLUGINS)."""
    out = []
    for kind in KINDS:
        for path in sorted((STDLIB / kind).glob("*.rdsl")):
            if path.stem not in SKIP_FILES:
                out += [d for d in declarations(path)
                        if d.kind in KINDS and d.name not in SKIP_PLUGINS]
    return out


HEAD = ("plugin", "variant", "cases", "NaN", "Inf", "negative", "energy gain", "mismatch",
        "NaN/Inf params (propagated, garbage)")


def table_row(name: str, variant: str, c: Counts) -> tuple[str, ...]:
    return (name, variant, str(c.cases), str(c.nan), str(c.inf), str(c.negative),
            str(c.energy_gain), str(c.mismatch),
            f"{c.bad_param_cases} ({c.bad_param_propagated}, {c.bad_param_garbage})")


def format_table(rows: list[tuple[str, ...]]) -> str:
    widths = [max(len(r[i]) for r in [HEAD] + rows) for i in range(len(HEAD))]
    line = lambda r: "  ".join(x.ljust(w) for x, w in zip(r, widths)).rstrip()  # noqa: E731
    return "\n".join([line(HEAD), line(["-" * w for w in widths])] + [line(r) for r in rows])


def add_command(sub: argparse._SubParsersAction) -> dict[str, Callable[[Any], int]]:
    """Add ``stress`` to ``sub``; returns its handler by name."""
    s = sub.add_parser("stress", help="sweep every stdlib BSDF, emitter and texture (or the "
                       "given plugins) over its domain; count NaN, Inf, negative values, "
                       "energy gain and pdf/eval mismatches")
    s.add_argument("files", nargs="*", help="plugin .rdsl files (default: the stdlib's)")
    s.add_argument("--variants", default="rgb,spectral",
                   help="comma-separated variants (default: rgb,spectral)")
    s.add_argument("--plugins", default=None,
                   help="comma-separated plugin names to keep (default: all)")
    s.add_argument("--fast", action="store_true", help="fewer values and samples (CI)")
    return {"stress": stress_command}


def _selected(args: Any) -> list[Declaration]:
    from ...compiler.diagnostics import CompileError
    from ...compiler.ir import Loc
    from .cli import choose

    decls = stdlib_plugins() if not args.files else []
    for f in map(Path, args.files):
        if f.suffix != ".rdsl" or not f.is_file():
            choose(f, None)  # the test kit's message for a missing or wrong file
        found = [d for d in declarations(f) if d.kind in KINDS]
        if not found:
            raise CompileError(f"declares no {', '.join(KINDS)} plugin to stress; expected "
                               "`bsdf NAME {`, `emitter NAME {` or `texture NAME {`",
                               Loc(str(f), 0, 0))
        decls += found
    if args.plugins:
        keep = set(args.plugins.split(","))
        unknown = keep - {d.name for d in decls}
        if unknown:
            raise CompileError(f"--plugins: no plugin {', '.join(sorted(unknown))} here "
                               f"(known: {', '.join(d.name for d in decls)})")
        decls = [d for d in decls if d.name in keep]
    return decls


def stress_command(args: Any) -> int:
    from ...compiler.build import Build

    variants = [Build.of("host", v).model.name for v in args.variants.split(",")]
    decls = _selected(args)
    rows, notes, failed = [], [], False
    t0 = time.perf_counter()
    for decl in decls:
        for v in variants:
            c = stress_plugin(decl, v, args.fast)
            rows.append(table_row(decl.name, v, c))
            failed |= c.failed()
            notes += [f"  {decl.name} ({v}): {n}" for n in c.notes.values()]
    print(format_table(rows))
    if not args.files:
        for name, why in SKIP_PLUGINS.items():
            print(f"not swept: {name}: {why}")
    if notes:
        print("first problems found:")
        print("\n".join(notes))
    print(f"{len(decls)} plugin(s) x {len(variants)} variant(s) in "
          f"{time.perf_counter() - t0:.0f} s: " + ("FAIL" if failed else "all counts zero"))
    sys.stdout.flush()
    return 1 if failed else 0


__all__ = ["Counts", "add_command", "stress_plugin", "param_sets", "stdlib_plugins"]
