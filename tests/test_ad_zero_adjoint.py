"""A zero adjoint through an infinite local partial (inf * 0 = NaN) must contribute 0:
the side of a ``select`` or an ``if`` not taken (``sqrt`` at 0, a division by 0, ``pow``
at 0) has an infinite partial where its adjoint is 0.  Checked against analytic values,
forward mode (whose zero tangents are guarded the same way), and central differences of
roughplastic.eval's d/d alpha (which was NaN in
every lane without elimination), with and without graph elimination, which composes the
guarded partials (a zero adjoint or a zero partial upstream stays 0) and must store no more
than it does with the guards left out."""

from __future__ import annotations

import numpy as np
import pytest

import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.passes import ad_reverse

from test_ad_eliminate import BSDF, _surface, _tape


def _half_rsqrt(x, other):
    return np.where(x > 0, 0.5 / np.sqrt(np.maximum(x, 1e-30)), other)


# name: (expression, its analytic derivative)
KERNELS = {
    "sel_sqrt": ("select(x > 0.0, sqrt(x), 0.0)", lambda x: _half_rsqrt(x, 0.0)),
    "sel_div": ("select(x > 0.0, 1.0 / x, 0.0) + x",
                lambda x: np.where(x > 0, -1.0 / np.maximum(x, 1e-30) ** 2, 0.0) + 1.0),
    "sel_pow": ("select(x > 0.0, pow(x, 0.5), 2.0 * x)", lambda x: _half_rsqrt(x, 2.0)),
}
IF_SRC = """
fn if_sqrt(x: Float) -> Float {
    var r = 3.0 * x;
    if x > 0.0 { r = sqrt(x); }
    return r;
}
"""
# c * sqrt(x) at c = 0, x = 0: the adjoint of sqrt(x) is a * c = 0 (not a zero adjoint
# tested by a guard of its own once elimination composes c with sqrt's infinite partial)
SCALED = "fn scaled(x: Float, c: Float) -> Float { return c * pow(x, 0.5); }\n"
SRC = "".join(f"fn {n}(x: Float) -> Float {{ return {e}; }}\n"
              for n, (e, _) in KERNELS.items()) + IF_SRC + SCALED


@pytest.fixture(scope="module", params=[0, 10], ids=["plain", "eliminate"])
def builds(request):
    return (rdsl.jit(SRC, build=Build.of("host", "rgb", ad="reverse",
                                         eliminate=request.param)),
            rdsl.jit(SRC, build=Build.of("host", "rgb", ad="forward")))


X = np.array([0.0, 0.0, -1.0, 0.25, 4.0], np.float32)


@pytest.mark.parametrize("name", [*KERNELS, "if_sqrt"])
def test_zero_adjoint_through_infinite_partial(builds, name):
    rev, fwd = builds
    x = X.astype(np.float64)
    want = KERNELS[name][1](x) if name in KERNELS else _half_rsqrt(x, 3.0)
    a = np.full(X.size, 2.0, np.float32)
    _, g = getattr(rev, name)(X, a)
    _, d = getattr(fwd, name)(X, np.ones_like(X))
    assert np.isfinite(g).all() and np.isfinite(d).all(), (g, d)
    np.testing.assert_allclose(g, 2.0 * want, rtol=1e-5)
    np.testing.assert_allclose(d, want, rtol=1e-5)


def test_zero_partial_upstream_of_an_infinite_one(builds):
    x = np.array([0.0, 0.0, 0.25, 4.0, 0.0], np.float32)
    c = np.array([0.0, 0.0, 2.0, 0.0, 3.0], np.float32)
    a = np.array([2.0, 0.0, 2.0, 2.0, 0.0], np.float32)
    _, gx, gc = builds[0].scaled(x, c, a)
    safe = np.maximum(x.astype(np.float64), 1e-30)
    want_x = np.where(c != 0, c * 0.5 / np.sqrt(safe), 0.0)
    np.testing.assert_allclose(gx, a * want_x, rtol=1e-5)
    np.testing.assert_allclose(gc, a * np.sqrt(x), rtol=1e-5)


def test_zero_tangent_through_an_infinite_partial(builds):
    """Forward mode along c of c * sqrt(x) at x = 0: x has tangent 0 there, so sqrt's
    infinite partial carries nothing (the derivative is sqrt(0) = 0, not NaN)."""
    x = np.array([0.0, 0.0, 0.25, 4.0], np.float32)
    c = np.array([0.0, 3.0, 2.0, 1.0], np.float32)
    zero, one = np.zeros_like(x), np.ones_like(x)
    y, d_c = builds[1].scaled(x, c, zero, one)
    np.testing.assert_allclose(d_c, np.sqrt(x), rtol=1e-6)
    _, d_x = builds[1].scaled(x, c, one, zero)  # along x: infinite where c != 0 at x = 0
    safe = np.maximum(x.astype(np.float64), 1e-30)
    np.testing.assert_allclose(d_x[2:], c[2:] * 0.5 / np.sqrt(safe[2:]), rtol=1e-5)
    assert d_x[0] == 0.0 and np.isinf(d_x[1])


@pytest.mark.parametrize("name", ["roughconductor", "roughplastic", "principled"])
def test_guards_cost_elimination_nothing(name, monkeypatch):
    """What the eliminated sweeps store, with the guards and with them left out (the
    sweep as it was before them, which gives NaN for roughplastic's d/d alpha)."""
    src, fn = BSDF / f"{name}.rdsl", f"{name}.eval"
    guarded = [t.values for t in _tape(src, 10, fn)[1]]
    monkeypatch.setattr(ad_reverse, "zero_guard", lambda b, a, p: p)
    bare = [t.values for t in _tape(src, 10, fn)[1]]
    off = [t.values for t in _tape(src, 0, fn)[1]]
    assert len(guarded) == len(bare) and all(map(int.__le__, guarded, bare)), (guarded, bare)
    assert sum(guarded) < sum(off)


@pytest.mark.parametrize("mode", ["reverse", "forward"])
def test_roughplastic_alpha_matches_central_differences_without_elimination(mode):
    """(With elimination: tests/test_ad_eliminate.py.)"""
    rng = np.random.default_rng(3)
    n = 16  # roughplastic's coating integrals run per lane without a scene's tables
    si, wo = _surface(n, rng), _surface(n, rng)["wi"]
    only = {"exports": ["roughplastic.eval"]}  # the file's other kernels are not built
    plain = rdsl.jit(BSDF / "roughplastic.rdsl", **only)["roughplastic.eval"]
    h = 1e-3
    fd = (np.asarray(plain(si, wo, alpha=0.25 + h), np.float64)
          - np.asarray(plain(si, wo, alpha=0.25 - h), np.float64)) / (2 * h)
    k = rdsl.jit(BSDF / "roughplastic.rdsl",
                 build=Build.of("host", "rgb", ad=mode, eliminate=0), **only)["roughplastic.eval"]
    leaves = k.result["leaves"]
    if mode == "reverse":
        a = np.stack([rng.standard_normal(n).astype(np.float32) for _ in range(3)], 1)
        got = np.asarray(k(si, wo, *a.T, alpha=0.25)[1 + leaves[3:].index("g.alpha")])
        want = (fd * a).sum(1)
    else:
        zeros = [np.zeros(n, np.float32)] * 20  # no tangent along si and wo
        d = {f"d_{p}{c}": 0.0 for p in ("diffuse_reflectance", "specular_reflectance")
             for c in (".x", ".y", ".z")}
        d.update(d_alpha=1.0, d_int_ior=0.0, d_ext_ior=0.0)
        out = k(si, wo, *zeros, alpha=0.25, **d)
        got = np.asarray(out[1], np.float64).reshape(n, -1)  # d.ret (grey: one column)
        got, want = np.broadcast_to(got, fd.shape), fd
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, want, rtol=0.05, atol=0.02)
