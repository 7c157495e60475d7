"""Per-scene tables (docs/language.md, "Tables"): a plugin's ``table(...) fn`` is computed once
per scene and read back by linear interpolation within the error the plugin states;
roughplastic's tables reproduce Mitsuba 3's (eval and pdf to ~1e-4 against its
``scalar_rgb`` plugin); the generic build fills them at scene load and renders the image
of the specialized build, which folds them at compile time."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import frontend
from rdsl.compiler.precompute import table_params, tabulate
from rdsl.core.scene_spec import Instance

STDLIB = Path(rdsl.__file__).resolve().parent / "stdlib"
f32 = np.float32


# ---------------------------------------------------------------------- the declaration

PLUGIN = """
bsdf tab {{
    param k: Float = 2.0;
    {decl}
    fn eval(si: Surface, wo: Vec3) -> Spectrum {{ return Spectrum(0.0); }}
    fn pdf(si: Surface, wo: Vec3) -> Float {{ return 0.0; }}
    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {{
        return BsdfSample {{ wo: si.wi, pdf: 0.0, eta: 1.0, weight: Spectrum(0.0),
                            delta: false }};
    }}
}}
"""


@pytest.mark.parametrize("decl, message", [
    ("table(n = 8, lo = 0.0, hi = 1.0) fn t(x: Float) -> Float { return x; }",
     "a table of one argument needs `error = ...`"),
    ("table(n = 8, lo = 1.0, hi = 1.0, error = 1e-3) fn t(x: Float) -> Float { return x; }",
     "`lo` must be less than `hi`"),
    ("table(n = 1, lo = 0.0, hi = 1.0, error = 1e-3) fn t(x: Float) -> Float { return x; }",
     "`n` must be an integer in 2..65536"),
    ("table(n = 8, lo = 0.0, hi = 1.0, error = 1e-3, step = 2) fn t(x: Float) -> Float "
     "{ return x; }", "unknown option `step`"),
    ("table fn t(x: Vec3) -> Float { return x.x; }",
     "a table is a `Float` function of no argument or of one `Float` argument"),
    ("table(n = 8, lo = 0.0, hi = 1.0, error = 1e-3) fn t() -> Float { return k; }",
     "a table of no argument is one value and takes no options"),
    ("table(sum = 8) fn t(x: Float) -> Float { return x; }",
     "a `sum` table is a `Float` function of one `Int` (the term's index)"),
    ("table(sum = 8, error = 1e-3) fn t(i: Int) -> Float { return Float(i); }",
     "a `sum` table takes no other option (found `error`)"),
    ("table(sum = 0) fn t(i: Int) -> Float { return Float(i); }",
     "`sum` (the number of terms) must be an integer in 1..65536"),
    ("table(sum = 4) fn t(i: Int) -> Float { return Float(i); }\n"
     "fn u() -> Float { return t(2); }",
     "`t` takes 0 arguments, found 1 (expected `t() -> Float`; a `sum` table is one value)"),
    ("table(sum = 4) fn t(i: Int) -> Float { return Float(i); }\n"
     "table fn u() -> Float { return t(); }",
     "`t` is a `sum` table: another table cannot read it"),
])
def test_bad_tables_are_diagnostics(decl, message):
    with pytest.raises(CompileError) as e:
        frontend(PLUGIN.format(decl=decl))
    assert message in str(e.value)


def _lerp(samples: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Mitsuba's lerp_gather on [0, 1], as the kernels read a table."""
    n = len(samples)
    t = x * f32(n - 1)
    i = np.minimum(t.astype(np.int32), n - 2)
    w = t - i
    return (1 - w) * samples[i] + w * samples[i + 1]


def _transmittance_errors(dist: int) -> tuple[dict, float]:
    """roughplastic's external_transmittance, sampled at its 64 points and interpolated,
    against the function itself at 8 points per interval (all of its domain): within the
    `error` it declares, and within the finer bounds its comment states."""
    module = frontend(STDLIB / "bsdf" / "roughplastic.rdsl")
    read = module.functions["roughplastic.external_transmittance.read"]
    opts = read.attrs["table"]
    fine = dict(opts, n=(opts["n"] - 1) * 8 + 1)
    x = np.linspace(0.0, 1.0, fine["n"]).astype(f32)
    worst = {"all": 0.0, "mu >= 1/63": 0.0, "alpha >= 0.1": 0.0}
    for alpha in (0.001, 0.01, 0.1, 0.3, 1.0):
        for int_ior in (1.1, 1.49, 2.5):
            params = table_params(read, Instance("roughplastic", {
                "alpha": alpha, "int_ior": int_ior, "distribution": dist}))
            coarse = tabulate(module, opts, params)
            exact = tabulate(module, fine, params)
            assert np.array_equal(exact[::8], coarse)  # the same function, the same points
            assert np.all((coarse >= 0) & (coarse <= 1)), (alpha, int_ior)
            err = np.abs(_lerp(coarse, x) - exact)
            worst["all"] = max(worst["all"], float(err.max()))
            worst["mu >= 1/63"] = max(worst["mu >= 1/63"], float(err[8:].max()))
            if alpha >= 0.1:
                worst["alpha >= 0.1"] = max(worst["alpha >= 0.1"], float(err.max()))
    return worst, opts["error"]


@pytest.mark.parametrize("dist", [0, 1])
def test_transmittance_table_within_its_stated_error(dist):
    worst, error = _transmittance_errors(dist)
    assert worst["all"] <= error, worst
    assert worst["mu >= 1/63"] <= 3.2e-3 and worst["alpha >= 0.1"] <= 6e-4, worst
    print(f"distribution {dist}: worst interpolation errors {worst} "
          f"(declared {error:.0e})")


# ---------------------------------------------------------------------- against Mitsuba 3

@pytest.fixture(scope="module")
def mi():
    mitsuba = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    previous = mitsuba.variant()
    try:
        mitsuba.set_variant("scalar_rgb")
    except Exception as e:  # noqa: BLE001 - any failure means no cross-check here
        pytest.skip(f"mitsuba variant scalar_rgb unavailable: {e}")
    yield mitsuba
    if previous is not None:
        mitsuba.set_variant(previous)


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.02  # upper hemisphere, grazing angles included
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(f32)


def _surfaces(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": wi, "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def _mitsuba(mi, params: dict, wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, ...]:
    bsdf = mi.load_dict({"type": "roughplastic", **params})
    ctx = mi.BSDFContext()
    ev, pdf = [], []
    for a, b in zip(wi, wo):
        si = mi.SurfaceInteraction3f()
        si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
        si.wi = [float(x) for x in a]
        w = [float(x) for x in b]
        ev.append(np.array(bsdf.eval(ctx, si, w)))
        pdf.append(float(bsdf.pdf(ctx, si, w)))
    return np.array(ev), np.array(pdf)


CASES = [(dist, alpha, ior, nonlinear) for dist in ("ggx", "beckmann")
         for alpha in (0.05, 0.3, 0.8) for ior in (1.2, 1.49, 2.0) for nonlinear in (False,)]
CASES += [("ggx", 0.3, 1.49, True), ("beckmann", 0.02, 1.33, True)]


def test_roughplastic_matches_mitsuba(mi):
    """eval and pdf at 60 direction pairs for each of 20 parameter sets (the generic build:
    one compile, the tables filled per set at load) against Mitsuba 3's roughplastic."""
    from rdsl.runtime.testkit.harness import Harness

    h = Harness("roughplastic", "rgb")
    rng = np.random.default_rng(11)
    worst = {"eval": 0.0, "pdf": 0.0}
    for dist, alpha, ior, nonlinear in CASES:
        wi, wo = _directions(rng, 60), _directions(rng, 60)
        diffuse = (0.7, 0.4, 0.1)
        ours = dict(distribution=int(dist == "beckmann"), alpha=alpha, int_ior=ior,
                    nonlinear=nonlinear, diffuse_reflectance=diffuse)
        ev = np.asarray(h.eval(_surfaces(wi), wo, **ours))
        pdf = np.asarray(h.pdf(_surfaces(wi), wo, **ours))
        theirs = dict(distribution=dist, alpha=alpha, int_ior=ior, nonlinear=nonlinear,
                      diffuse_reflectance={"type": "rgb", "value": list(diffuse)})
        mev, mpdf = _mitsuba(mi, theirs, wi, wo)
        where = f"{dist} alpha={alpha} int_ior={ior} nonlinear={nonlinear}"
        rel_e = np.abs(ev - mev) / np.maximum(np.abs(mev), 1e-3)
        rel_p = np.abs(pdf - mpdf) / np.maximum(mpdf, 1e-3)
        worst["eval"] = max(worst["eval"], float(rel_e.max()))
        worst["pdf"] = max(worst["pdf"], float(rel_p.max()))
        assert rel_e.max() < 1e-4, (where, rel_e.max())
        assert rel_p.max() < 1e-4, (where, rel_p.max())
    print(f"worst relative difference to Mitsuba 3: eval {worst['eval']:.1e}, "
          f"pdf {worst['pdf']:.1e}")


def test_specialized_tables_match_mitsuba(mi):
    """The specialized build folds the same tables at compile time."""
    from rdsl.core.scene_spec import SceneSpec

    src = """
import render.scene;
import bsdf.roughplastic;
fn ev(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
"""
    params = [dict(alpha=0.2, int_ior=1.6), dict(alpha=0.5, distribution=1)]
    mod = rdsl.jit(src, target="host",
                   scene=SceneSpec(bsdfs=[Instance("roughplastic", p) for p in params]))
    rng = np.random.default_rng(4)
    for k, (p, dist) in enumerate(zip(params, ("ggx", "beckmann"))):
        wi, wo = _directions(rng, 40), _directions(rng, 40)
        ours = np.asarray(mod.ev(np.full(40, k, np.int32), _surfaces(wi), wo, np.zeros(3, f32)))
        theirs, _ = _mitsuba(mi, dict(p, distribution=dist), wi, wo)
        rel = np.abs(ours - theirs) / np.maximum(np.abs(theirs), 1e-3)
        assert rel.max() < 1e-4, (k, rel.max())


# ---------------------------------------------------------------------- generic build

def test_generic_build_renders_the_specialized_image(tmp_path):
    """Two roughplastic instances whose tables differ: folded at compile time in one build,
    filled in PRM at load in the other; the images agree."""
    pytest.importorskip("rdsl.runtime.embree")
    from test_generic_build import same_image
    from test_scene_bsdfs import OBLIQUE, scene_xml

    spheres = "".join(
        f'<shape type="sphere"><point name="center" value="{x}, 0, 1"/>'
        f'<float name="radius" value="1"/><bsdf type="roughplastic">{b}</bsdf></shape>'
        for x, b in ((-1.2, '<float name="alpha" value="0.15"/>'),
                     (1.2, '<string name="distribution" value="ggx"/>'
                           '<float name="alpha" value="0.5"/><float name="int_ior" value="1.7"/>'
                           '<rgb name="diffuse_reflectance" value="0.2, 0.5, 0.8"/>')))
    body = ('<shape type="rectangle"><transform name="to_world"><scale value="4"/>'
            '<translate z="8"/></transform><boolean name="flip_normals" value="true"/>'
            '<emitter type="area"><rgb name="radiance" value="3, 3, 3"/></emitter></shape>'
            '<emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>' + spheres)
    path = tmp_path / "rp.xml"
    path.write_text(scene_xml(body, OBLIQUE, res=24))
    print(same_image(path, spp=4))


def test_a_table_cannot_depend_on_a_texture():
    from rdsl.core.scene_spec import TextureRef

    module = frontend(STDLIB / "bsdf" / "roughplastic.rdsl")
    read = module.functions["roughplastic.external_transmittance.read"]
    params = table_params(read, Instance("roughplastic", {"alpha": TextureRef(0)}))
    with pytest.raises(CompileError, match="depends on `alpha`, which the scene sets by a "
                                           "texture"):
        tabulate(module, read.attrs["table"], params)
    # a texture on a parameter the table does not use is fine
    params = table_params(read, Instance("roughplastic", {"diffuse_reflectance": TextureRef(0)}))
    assert tabulate(module, read.attrs["table"], params).shape == (64,)


# ---------------------------------------------------------------------- sum tables

SUMMED = """
bsdf summed {
    param k: Float = 0.5;
    param terms: Int = 1000;
    /// sum over i < 1000 of k^i / i!  (e^k, its terms past `terms` zero)
    table(sum = 1000) fn series(i: Int) -> Float {
        var t = 1.0;
        for j in 1..i + 1 { t = t * k / Float(j); }
        return select(i < terms, t, 0.0);
    }
    fn eval(si: Surface, wo: Vec3) -> Spectrum { return Spectrum(series()); }
    fn pdf(si: Surface, wo: Vec3) -> Float { return 0.0; }
    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {
        return BsdfSample { wo: si.wi, pdf: 0.0, eta: 1.0, weight: Spectrum(0.0),
                            delta: false };
    }
}
"""


def test_a_sum_table_is_read_only_inside_its_plugin():
    with pytest.raises(CompileError, match=r"`summed.series` is a `sum` table, read only "
                                           r"inside its plugin") as e:
        frontend(SUMMED + "fn outside() -> Float { return summed.series(); }\n")
    assert e.value.diagnostics[0].loc.line == SUMMED.count("\n") + 1


@pytest.mark.parametrize("k, terms", [(0.5, 1000), (-1.25, 1000), (2.0, 3)])
def test_a_sum_table_is_the_sum_of_its_terms(k, terms):
    """``table(sum = N)``: one value per instance, the N terms computed as the points of a
    table (side by side, in lanes) and summed in float64; against the float64 series."""
    module = frontend(SUMMED)
    read = module.functions["summed.series.read"]
    assert [p.value.name for p in read.params][:2] == ["k", "terms"]  # no term index
    params = table_params(read, Instance("summed", {"k": k, "terms": terms}))
    got = tabulate(module, read.attrs["table"], params)
    term, want = 1.0, 0.0
    for i in range(terms):
        want, term = want + term, term * k / (i + 1)
    assert got.shape == (1,) and got.dtype == np.float32
    assert got[0] == pytest.approx(want, rel=3e-6)


def test_a_sum_table_reads_its_value_in_both_builds_and_computes_it_without_a_scene():
    """Without a scene the read computes the sum itself (in order, in float32); the
    specialized build folds the precomputed value, the generic one reads it from PRM."""
    from rdsl.core.scene_spec import SceneSpec

    si = _surfaces(_directions(np.random.default_rng(1), 4))
    wo = si["wi"]
    plain = rdsl.jit(SUMMED, target="host")["summed.eval"]
    exact = np.asarray(plain(si, wo, k=0.75))[:, 0]
    np.testing.assert_allclose(exact, math.exp(0.75), rtol=1e-6)
    scene_src = SUMMED + """
import render.scene;
fn ev(id: Int, si: Surface, wo: Vec3, T: [Float]) -> Spectrum {
    return scene_bsdf_eval(id, si, wo, T);
}
"""
    spec = SceneSpec(bsdfs=[Instance("summed", {"k": 0.75}), Instance("summed", {"k": 2.0})])
    mod = rdsl.jit(scene_src, target="host", scene=spec)
    for i, k in enumerate((0.75, 2.0)):
        got = np.asarray(mod.ev(np.full(4, i, np.int32), si, wo, np.zeros(3, f32)))[:, 0]
        np.testing.assert_allclose(got, math.exp(k), rtol=3e-6)


# ---------------------------------------------------------------------- the kernel on disk

_OTHER_PROCESS = """
import sys
import numpy as np
import math
from pathlib import Path
import rdsl.compiler.precompute as pc
from rdsl.compiler.driver import frontend
from rdsl.core.scene_spec import Instance

built = []
compile_ = pc._compile
pc._compile = lambda *a: built.append(1) or compile_(*a)
module = frontend(Path(sys.argv[1]))
read = module.functions["roughplastic.external_transmittance.read"]
params = pc.table_params(read, Instance("roughplastic", {"alpha": float(sys.argv[2])}))
np.save(sys.argv[3], pc.tabulate(module, read.attrs["table"], params))
print("built", len(built))
"""


def test_a_table_kernel_built_once_serves_other_processes_and_values(tmp_path):
    """A process that tabulates a plugin's table for values not cached yet loads the kernel
    another process built (it compiles nothing) and gets the samples this process computes;
    with the kernel's library gone, it builds it again."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, RDSL_CACHE_DIR=str(tmp_path / "cache"))
    src = STDLIB / "bsdf" / "roughplastic.rdsl"

    def run(alpha: float) -> tuple[int, np.ndarray]:
        out = tmp_path / f"{alpha}.npy"
        p = subprocess.run([sys.executable, "-c", _OTHER_PROCESS, str(src), str(alpha),
                            str(out)], env=env, capture_output=True, text=True, timeout=300)
        assert p.returncode == 0, p.stderr
        return int(p.stdout.split()[-1]), np.load(out)

    module = frontend(src)
    read = module.functions["roughplastic.external_transmittance.read"]
    here = {a: tabulate(module, read.attrs["table"],
                        table_params(read, Instance("roughplastic", {"alpha": a})))
            for a in (0.2, 0.4, 0.6)}
    built, samples = run(0.2)  # the first process builds the kernel
    assert built == 1 and np.array_equal(samples, here[0.2])
    built, samples = run(0.4)  # other values: the samples are not cached, the kernel is
    assert built == 0 and np.array_equal(samples, here[0.4])
    for so in (tmp_path / "cache" / "native").glob("*.so"):
        so.unlink()
    built, samples = run(0.6)
    assert built == 1 and np.array_equal(samples, here[0.6])
