"""Graph elimination (compiler/passes/eliminate.py) on reverse-mode kernels.

The truth is the reverse build without the pass (tests/test_ad_reverse.py checks that one
against forward mode and finite differences): elimination must change no gradient beyond
float rounding, on stdlib BSDF kernels, on a kernel with loops and branches and on a
render's ``backward``; and it must reduce what the sweeps keep of their forward parts
(compiler/passes/ad_tape.py), counted on the IR."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.driver import frontend, keep_exports, pipeline, run_passes
from rdsl.compiler.passes.ad_tape import tape
from rdsl.compiler.passes.eliminate import Eliminate
from rdsl.compiler.printer import print_module

from _scenes import CBOX
from test_ad_reverse import LOOP, NPRM

ROOT = Path(rdsl.__file__).resolve().parent
BSDF = ROOT / "stdlib" / "bsdf"
needs_cbox = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")


def _reverse(src, threshold, exports=None):
    """The reverse build of ``src`` (only the kernels ``exports`` names, when given)."""
    extra = {} if exports is None else {"exports": exports}
    return rdsl.jit(src, build=Build.of("host", "rgb", ad="reverse", eliminate=threshold),
                    **extra)


def _close(a, b, what):
    """Equal up to float rounding, relative to the largest magnitude of the same output,
    wherever ``a`` (without elimination) is finite."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    ok = np.isfinite(a)
    scale = max(float(np.max(np.abs(a[ok]), initial=0.0)), 1e-6)
    assert np.isfinite(b[ok]).all(), what
    np.testing.assert_allclose(a[ok], b[ok], rtol=2e-4, atol=2e-5 * scale, err_msg=what)


def _surface(n, rng):
    wi = rng.standard_normal((n, 3)).astype(np.float32)
    wi[:, 2] = np.abs(wi[:, 2]) + 0.05
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    z = np.zeros((n, 3), np.float32)
    return {"p": z, "n": z + [0, 0, 1], "sh_n": z + [0, 0, 1],
            "uv": rng.random((n, 2), np.float32), "wi": wi, "t": np.ones(n, np.float32),
            "valid": np.ones(n, bool)}


@pytest.mark.parametrize("name, params", [
    ("roughconductor", {"alpha": 0.3, "eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.2]}),
    ("principled", {}),
    ("roughplastic", {"alpha": 0.25}),
])
def test_bsdf_gradients_unchanged(name, params):
    rng = np.random.default_rng(3)
    # roughplastic's kernel integrates its coating per lane when alpha is not a scene
    # constant (the scene's tables are not there): 14 ms a lane at O0, so fewer lanes
    n = 16 if name == "roughplastic" else 64
    si, wo = _surface(n, rng), _surface(n, rng)["wi"]
    a = [rng.standard_normal(n).astype(np.float32) for _ in range(3)]
    outs = []
    for threshold in (0, 10):
        k = _reverse(BSDF / f"{name}.rdsl", threshold, [f"{name}.eval"])[f"{name}.eval"]
        outs.append(k(si, wo, *a, **params))
    assert len(outs[0]) > 3  # the value and the gradients of the Float arguments
    for i, (u, v) in enumerate(zip(*outs)):
        _close(u, v, f"{name}.eval output {i}")
    nonzero = [i for i, u in enumerate(outs[0][1:]) if np.any(np.asarray(u) != 0)]
    assert len(nonzero) >= 4  # wi, wo and the BSDF's parameters have gradients


def test_roughplastic_alpha_matches_central_differences():
    """Found by the test above: the sweep without elimination gave NaN for d/d alpha of
    roughplastic.eval (an inf * 0 in ad_reverse's sweep, now guarded: tests/
    test_ad_zero_adjoint.py); with elimination it is finite and agrees with central
    differences of the plain kernel."""
    rng = np.random.default_rng(3)
    n = 16  # as above: the coating's integrals run per lane
    si, wo = _surface(n, rng), _surface(n, rng)["wi"]
    a = np.stack([rng.standard_normal(n).astype(np.float32) for _ in range(3)], 1)
    k = _reverse(BSDF / "roughplastic.rdsl", 10, ["roughplastic.eval"])["roughplastic.eval"]
    got = np.asarray(k(si, wo, *a.T, alpha=0.25)[1 + k.result["leaves"][3:].index("g.alpha")])
    plain = rdsl.jit(BSDF / "roughplastic.rdsl",
                     exports=["roughplastic.eval"])["roughplastic.eval"]
    h = 1e-3
    fd = (np.asarray(plain(si, wo, alpha=0.25 + h), np.float64)
          - np.asarray(plain(si, wo, alpha=0.25 - h), np.float64)) / (2 * h)
    np.testing.assert_allclose(got, (fd * a).sum(1), rtol=0.05, atol=0.02)


def test_loop_and_branch_gradients_unchanged():
    x = np.linspace(-0.5, 2.0, 37).astype(np.float32)
    prm = np.array([0.7, 1.3, 0.8, 2.0, 0.9], np.float32)
    a = np.random.default_rng(0).standard_normal(x.size).astype(np.float32)
    got = []
    for threshold in (0, 10):
        grad = np.zeros(x.size * NPRM, np.float32)
        value, gx = _reverse(LOOP, threshold).k(
            x, prm, a, grad, np.arange(x.size, dtype=np.int32) * NPRM)
        got.append((value, gx, grad))
    np.testing.assert_array_equal(got[0][0], got[1][0])  # the primal value is untouched
    _close(got[0][1], got[1][1], "d/dx")
    _close(got[0][2], got[1][2], "d/dPRM")


def _tape(source, threshold, fn, spec=None, search=None):
    m = frontend(source, "k.rdsl", search) if isinstance(source, str) else frontend(source)
    keep_exports(m, [fn])  # the other kernels of the file are not compiled
    build = Build.of("host", "rgb", ad="reverse", eliminate=threshold)
    run_passes(m, pipeline(build, spec), out=io.StringIO(),
               stop_after="eliminate" if threshold else "ad_reverse")
    return m, tape(m.functions[fn])


@pytest.mark.parametrize("name", ["roughconductor", "principled", "roughdielectric"])
def test_elimination_stores_fewer_values(name):
    _, off = _tape(BSDF / f"{name}.rdsl", 0, f"{name}.eval")
    _, on = _tape(BSDF / f"{name}.rdsl", 10, f"{name}.eval")
    assert [t.kind for t in off] == [t.kind for t in on] == ["kernel"]
    assert on[0].values < off[0].values
    assert on[0].bytes == 4 * on[0].values


def test_threshold_zero_is_the_pass_off_and_the_threshold_matters():
    for t in (0, False):
        names = [p.name for p in pipeline(Build.of("host", "rgb", ad="reverse", eliminate=t))]
        assert "ad_reverse" in names and "eliminate" not in names
    m = frontend(BSDF / "roughconductor.rdsl")
    run_passes(m, pipeline(Build.of("host", "rgb", ad="reverse")), out=io.StringIO(),
               stop_after="ad_reverse")
    before = print_module(m)
    Eliminate(0).run(m)
    assert print_module(m) == before  # threshold 0: the IR is untouched
    Eliminate(10).run(m)
    assert print_module(m) != before
    counts = [_tape(BSDF / "roughconductor.rdsl", t, "roughconductor.eval")[1][0].values
              for t in (0, 2, 10)]
    assert counts[2] < counts[0]  # the default threshold keeps fewer values than none
    assert len(set(counts)) == 3  # and the threshold changes what is eliminated (164, 136,
    # 79 here; threshold 1 would read more than none, so the pass leaves that one alone)


def test_bad_thresholds_are_clear_errors():
    with pytest.raises(CompileError, match="non-negative integer"):
        Build.of("host", "rgb", ad="reverse", eliminate=-1)
    with pytest.raises(CompileError, match="reverse build"):
        Build.of("host", "rgb", ad="forward", eliminate=10)


def test_rdsl_ir_prints_after_eliminate(tmp_path):
    src = tmp_path / "k.rdsl"
    src.write_text(LOOP)
    run = [sys.executable, "-m", "rdsl.cli", "ir", str(src), "--ad", "reverse",
           "--no-locs", "--print-after"]
    out = subprocess.run(run + ["eliminate"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert "// ----- after eliminate -----" in out.stdout
    before = subprocess.run(run + ["ad_reverse"], capture_output=True, text=True).stdout
    assert out.stdout.split("\n", 1)[1] != before.split("\n", 1)[1]
    off = subprocess.run(run + ["eliminate", "--eliminate", "0"], capture_output=True,
                         text=True)
    assert off.returncode == 0 and "after eliminate" not in off.stdout
    fwd = subprocess.run(run[:5] + ["--print-after", "eliminate"], capture_output=True,
                         text=True)
    assert fwd.returncode == 1 and "add --ad reverse" in fwd.stderr
    assert "Traceback" not in fwd.stderr


def _bounce_tapes(scene):
    """The bounce loop's tape values of ``scene``'s adjoint render kernel without and with
    elimination (the generic build's, every parameter differentiated)."""
    from rdsl.compiler.passes.specialize import parameter_slots

    scene.use_generic()
    scene._kernel_inputs()  # the generic build's source and scene, without compiling it
    spec = parameter_slots(scene.scene_spec, scene.build.model)[0]
    tapes = [_tape(scene.kernel_src, t, "render_sample", spec, scene.search_paths)[1]
             for t in (0, 10)]
    bounce = [[t for t in ts if t.kind == "loop"] for ts in tapes]
    assert len(bounce[0]) == len(bounce[1]) >= 1
    return bounce[0][0].values, bounce[1][0].values


@needs_cbox
def test_cbox_backward_unchanged_and_bounce_tape_not_larger():
    scene = rdsl.load_scene(CBOX, res=16, max_depth=3)
    d = np.random.default_rng(1).standard_normal((16, 16, 3))
    names = ["red.reflectance.value", "light.emitter.radiance.value"]
    off = scene.backward(d, names, spp=2, seed=3)
    on = scene.backward(d, names, spp=2, seed=3, eliminate=True)
    for n in names:
        np.testing.assert_allclose(on[n], off[n], rtol=1e-4, atol=1e-5 * np.abs(off[n]).max())
        assert np.abs(off[n]).max() > 0
    # diffuse walls: little to eliminate, and what greedy elimination would do here reads
    # one value more, so the pass leaves the kernel as it was (its guarantee)
    without, with_ = _bounce_tapes(scene)
    assert with_ <= without


@needs_cbox
def test_bounce_tape_smaller_with_a_rough_conductor(tmp_path):
    # a rough conductor's GGX terms are where elimination pays (the Table 2):
    # 1156 -> 853 values per bounce measured here (bench/ad_eliminate.py)
    xml = CBOX.read_text().replace(
        '<bsdf type="diffuse" id="green">\n        <rgb name="reflectance" '
        'value="0.105421, 0.37798, 0.076425"/>',
        '<bsdf type="roughconductor" id="green">\n        <float name="alpha" value="0.3"/>')
    assert "roughconductor" in xml
    (tmp_path / "cbox.xml").write_text(xml)
    scene = rdsl.load_scene(tmp_path / "cbox.xml", res=8, max_depth=3)
    scene.render(spp=1)
    without, with_ = _bounce_tapes(scene)
    assert with_ < 0.9 * without
