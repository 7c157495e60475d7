"""Mitsuba 3's `pplastic` (stdlib/bsdf/pplastic.rdsl): the Mueller matrices of eval() and the
weights and pdfs of sample() against Mitsuba's own BSDF (mono_polarized against its
scalar_spectral_polarized, four equal wavelengths; the helpers of
tests/test_polarized_bsdfs_mitsuba.py), eval() in rgb against scalar_rgb, `rdsl test-plugin`
(chi-square of sample() against pdf(), weight == eval / pdf, energy, finite values) in every
variant, a scene against Mitsuba's image, and bad parameters at their line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import block_error, mitsuba_variant, render_both, scene_header
from test_polarized_bsdfs_mitsuba import (
    _call,
    _directions,
    _matrices,
    _mi_matrix,
    _mi_si,
    _rel_err,
    _surfaces,
    check_sample_weights,
    mitsuba_polarized,
)

ROOT = Path(__file__).resolve().parents[1]
f32 = np.float32
DIRS = _directions([0, 5, 30, 56.3, 80], [0.3, 2.0, -1.2])  # 0: along the normal
CASES = [  # (Mitsuba's parameters, rdsl's)
    ({"distribution": "ggx", "alpha_u": 0.15, "alpha_v": 0.3, "int_ior": 1.5, "ext_ior": 1.0,
      "diffuse_reflectance": 0.4},
     {"distribution": 0, "alpha": 0.15, "alpha_v": 0.3, "int_ior": 1.5, "ext_ior": 1.0,
      "diffuse_reflectance": 0.4}),
    ({"alpha": 0.3, "diffuse_reflectance": 0.7, "specular_reflectance": 0.6},
     {"distribution": 1, "alpha": 0.3, "int_ior": 1.49, "ext_ior": 1.000277,
      "diffuse_reflectance": 0.7, "specular_reflectance": 0.6}),
]


@pytest.fixture(scope="module")
def mi():
    yield from mitsuba_polarized()


@pytest.mark.parametrize("case", range(len(CASES)))
def test_polarized_eval_matches_mitsuba(mi, case):
    """Every entry of the Mueller matrix, for every pair of a direction grid."""
    mi_params, params = CASES[case]
    bsdf = mi.load_dict({"type": "pplastic", **mi_params})
    ctx = mi.BSDFContext()
    wi = np.repeat(DIRS, len(DIRS), axis=0)
    wo = np.tile(DIRS, (len(DIRS), 1))
    n = len(wi)
    ours = _matrices(_call("pplastic", "eval", _surfaces(wi), wo.astype(f32), **params), n)
    polarizing = 0
    for i in range(n):
        theirs = _mi_matrix(bsdf.eval(ctx, _mi_si(mi, wi[i]), [float(x) for x in wo[i]]))
        assert _rel_err(ours[i], theirs) < 2e-5, (wi[i], wo[i], ours[i], theirs)
        polarizing += np.abs(theirs[0, 1:]).max() > 1e-3 * theirs[0, 0]
    assert polarizing > n // 2  # the matrices are not depolarizers


@pytest.mark.parametrize("case", range(len(CASES)))
def test_polarized_sample_matches_mitsuba(mi, case):
    """Each sample's pdf is Mitsuba's pdf() of its direction and its weight Mitsuba's
    eval / pdf there (the visible-normal samplers map random numbers differently)."""
    mi_params, params = CASES[case]
    check_sample_weights(mi, "pplastic", mi_params, params, 2e-4, DIRS)


def test_rgb_eval_matches_mitsuba():
    from rdsl.runtime.testkit.harness import Harness

    h = Harness("pplastic", "rgb")
    wi = np.repeat(DIRS, len(DIRS), axis=0)
    wo = np.tile(DIRS, (len(DIRS), 1))
    params = {"distribution": 0, "alpha": 0.2, "diffuse_reflectance": (0.6, 0.3, 0.1)}
    ours = h.eval(_surfaces(wi), wo.astype(f32), **params)
    ours_pdf = h.pdf(_surfaces(wi), wo.astype(f32), **params)
    with mitsuba_variant("scalar_rgb") as m:
        bsdf = m.load_dict({"type": "pplastic", "distribution": "ggx", "alpha": 0.2,
                            "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.3, 0.1]}})
        ctx = m.BSDFContext()
        theirs, theirs_pdf = [], []
        for a, b in zip(wi, wo):
            si = m.SurfaceInteraction3f()
            si.sh_frame, si.wi = m.Frame3f([0, 0, 1]), [float(x) for x in a]
            theirs.append(np.array(bsdf.eval(ctx, si, [float(x) for x in b])))
            theirs_pdf.append(bsdf.pdf(ctx, si, [float(x) for x in b]))
    np.testing.assert_allclose(ours, np.array(theirs), rtol=1e-4, atol=1e-6)
    # Mitsuba's sampling weight is the mean of its texture (here = the mean at the point)
    np.testing.assert_allclose(ours_pdf, np.array(theirs_pdf, float), rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("variant", ["rgb", "mono", "spectral", "mono_polarized",
                                     "spectral_polarized"])
def test_passes_the_test_kit(capsys, variant: str):
    from rdsl.cli import main

    rc = main(["test-plugin", str(ROOT / "stdlib" / "bsdf" / "pplastic.rdsl"), "-p",
               "alpha=0.2", "-p", "diffuse_reflectance=0.8", "--variant", variant,
               "--samples", "100000"])
    out = capsys.readouterr().out
    assert rc == 0 and " FAIL" not in out, out
    assert out.count("chi2 sample vs pdf") >= 3 and "weight == eval/pdf" in out, out


SCENE = scene_header("0, -3, 2", "0, 0, 0", "0, 0, 1", fov=40, res=24, max_depth=3) + """
  <shape type="sphere"><float name="radius" value="0.8"/>
    <bsdf type="pplastic"><rgb name="diffuse_reflectance" value="0.3, 0.1, 0.5"/>
      <float name="alpha" value="0.15"/></bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="3"/><translate z="-0.8"/></transform>
    <bsdf type="pplastic"><rgb name="diffuse_reflectance" value="0.2, 0.5, 0.2"/>
      <float name="alpha" value="0.3"/><string name="distribution" value="ggx"/>{extra}</bsdf>
  </shape>
  <emitter type="point"><point name="position" x="1.5" y="-1.5" z="2.5"/>
    <rgb name="intensity" value="12, 12, 12"/></emitter>
  <emitter type="constant"><rgb name="radiance" value="0.2"/></emitter>
</scene>
"""


@pytest.mark.parametrize("variant", ["rgb", "spectral"])
def test_scene_matches_mitsuba(tmp_path: Path, variant: str):
    path = tmp_path / "pplastic.xml"
    path.write_text(SCENE.format(extra=""))
    img, ref = render_both(path, variant, 256)
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.02)
    assert block_error(img, ref) < 0.06


@pytest.mark.parametrize("extra,message", [
    ('<float name="int_ior" value="-1"/>', "int_ior"),
    ('<boolean name="nonlinear" value="true"/>', "unknown parameter 'nonlinear'"),
    ('<string name="distribution" value="phong"/>', "distribution"),
])
def test_bad_parameters_are_errors_at_their_line(tmp_path: Path, extra: str, message: str):
    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.renderer import load_scene

    path = tmp_path / "pplastic.xml"
    path.write_text(SCENE.format(extra=extra))
    line = 1 + next(i for i, s in enumerate(path.read_text().splitlines()) if extra in s)
    with pytest.raises(CompileError) as e:
        load_scene(path)
    assert f"{path}:{line}:" in str(e.value) and message in str(e.value), str(e.value)
