"""The `principled` and `principledthin` BSDFs (stdlib/bsdf/principled.rdsl and
principledthin.rdsl, Mitsuba 3's principled.cpp and principledthin.cpp) against Mitsuba 3
itself: eval() and pdf() of scenes' principled BSDFs (parameters as Mitsuba takes
them, `specular` and `eta` included) at directions over the whole sphere, in scalar_rgb and
scalar_spectral; sample() against pdf() by the test kit's chi-square (and its other checks)
for lobe mixes that exercise every lobe, in every variant; and the loader's errors."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rdsl
from _bsdf_harness import SceneBsdfs
from _mitsuba_render import block_error, mitsuba_variant, render_both, scene_header
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.scene.loader import load_scene_description

f32 = np.float32
ROOT = Path(__file__).resolve().parents[1]
CASES: list[tuple[str, dict[str, Any]]] = [
    ("principled", {}),  # Mitsuba's defaults: base_color 0.5, roughness 0.5, specular 0.5
    ("principled", {"base_color": (0.8, 0.3, 0.1), "metallic": 0.7, "roughness": 0.3,
                    "spec_tint": 0.4}),
    ("principled", {"base_color": (0.2, 0.6, 0.9), "spec_trans": 0.8, "eta": 1.33,
                    "roughness": 0.25}),
    ("principled", {"base_color": (0.9, 0.8, 0.3), "sheen": 0.8, "sheen_tint": 0.6,
                    "flatness": 0.5, "clearcoat": 0.7, "clearcoat_gloss": 0.4,
                    "roughness": 0.6}),
    ("principled", {"base_color": (0.5, 0.9, 0.4), "anisotropic": 0.6, "roughness": 0.4,
                    "metallic": 0.3, "specular": 0.8, "spec_trans": 0.4, "clearcoat": 0.5,
                    "main_specular_sampling_rate": 2.0,
                    "diffuse_reflectance_sampling_rate": 0.5,
                    "clearcoat_sampling_rate": 0.3}),
    ("principledthin", {}),
    ("principledthin", {"base_color": (0.8, 0.3, 0.1), "spec_trans": 0.7, "eta": 1.4,
                        "roughness": 0.3, "spec_tint": 0.5}),
    ("principledthin", {"base_color": (0.3, 0.7, 0.5), "diff_trans": 1.2, "sheen": 0.8,
                        "sheen_tint": 0.4, "flatness": 0.6, "anisotropic": 0.5,
                        "spec_trans": 0.3, "roughness": 0.45,
                        "specular_reflectance_sampling_rate": 2.0,
                        "diffuse_transmittance_sampling_rate": 0.5}),
]
# the test kit's -p options per plugin: lobe mixes for sample() vs pdf(); the second has
# every lobe
MIXES = {
    "principled": [
        [],
        ["spec_trans=0.6", "clearcoat=0.8", "roughness=0.3", "anisotropic=0.5",
         "metallic=0.2", "sheen=0.5", "spec_tint=0.3", "sheen_tint=0.5", "flatness=0.4",
         "base_color=0.8,0.5,0.2"],
        ["spec_trans=1.0", "roughness=0.15", "eta=1.6"],
    ],
    "principledthin": [
        [],
        ["spec_trans=0.6", "diff_trans=0.8", "roughness=0.3", "anisotropic=0.5", "sheen=0.5",
         "spec_tint=0.3", "sheen_tint=0.5", "flatness=0.4", "base_color=0.8,0.5,0.2",
         "eta=1.4"],
        ["spec_trans=1.0", "roughness=0.15", "eta=1.6"],
    ],
}


def _xml_value(name: str, value: Any) -> str:
    if isinstance(value, tuple):
        return f'<rgb name="{name}" value="{", ".join(map(str, value))}"/>'
    return f'<float name="{name}" value="{value}"/>'


def _scene(tmp_path: Path, cases: list[tuple[str, dict[str, Any]]]) -> Path:
    shapes = "".join(f'<shape type="sphere"><bsdf type="{kind}">'
                     + "".join(_xml_value(k, v) for k, v in case.items())
                     + "</bsdf></shape>" for kind, case in cases)
    path = tmp_path / "principled.xml"
    path.write_text(f'<scene version="3.0.0">{shapes}</scene>')
    return path


def _mi_dict(case: dict[str, Any], kind: str = "principled") -> dict[str, Any]:
    out: dict[str, Any] = {"type": kind}
    for k, v in case.items():
        out[k] = {"type": "rgb", "value": list(v)} if isinstance(v, tuple) else v
    return out


@pytest.fixture(params=["rgb", "spectral"])
def variant(request) -> Iterator[tuple[str, Any]]:
    with mitsuba_variant(f"scalar_{request.param}") as mi:
        yield request.param, mi


def _sphere(n: int, seed: int) -> np.ndarray:
    """n directions uniform on the sphere, none within 1e-3 of the horizon."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(4 * n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return v[np.abs(v[:, 2]) > 1e-3][:n].astype(f32)


def _surfaces(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def _mitsuba(mi: Any, bsdf: Any, wi: np.ndarray, wo: np.ndarray,
             lam: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    ctx = mi.BSDFContext()
    values, pdfs = [], []
    for j in range(len(wi)):
        si = mi.SurfaceInteraction3f()
        si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
        si.wi = [float(x) for x in wi[j]]
        if lam is not None:
            si.wavelengths = [float(x) for x in lam[j]]
        d = [float(x) for x in wo[j]]
        values.append(np.array(bsdf.eval(ctx, si, d), np.float64).ravel())
        pdfs.append(float(bsdf.pdf(ctx, si, d)))
    return np.array(values), np.array(pdfs)


def test_eval_and_pdf_match_mitsuba(tmp_path, variant):
    """At 400 (wi, wo) pairs over the sphere (reflection and transmission, from above and
    below; half of them near the specular directions, where the lobes peak) per case."""
    name, mi = variant
    bsdfs = SceneBsdfs(_scene(tmp_path, CASES), name)
    n = 400
    wi = _sphere(n, 3)
    wo = _sphere(n, 4)
    mirror = np.stack([-wi[:, 0], -wi[:, 1], wi[:, 2]], -1) + 0.15 * _sphere(n, 5)
    wo[: n // 2] = (mirror / np.linalg.norm(mirror, axis=1, keepdims=True))[: n // 2]
    for k, (kind, case) in enumerate(CASES):
        h = bsdfs[k]
        lam = h.wavelengths(n)
        ours_f = np.asarray(h.eval(_surfaces(wi), wo), np.float64).reshape(n, -1)
        ours_p = np.asarray(h.pdf(_surfaces(wi), wo), np.float64)
        theirs_f, theirs_p = _mitsuba(mi, mi.load_dict(_mi_dict(case, kind)), wi, wo, lam)
        assert ours_f.shape == theirs_f.shape
        assert (theirs_f > 0).any() and (theirs_p > 0).mean() > 0.3, case
        np.testing.assert_allclose(ours_f, theirs_f, rtol=5e-4, atol=1e-5 * theirs_f.max(),
                                   err_msg=f"eval {kind} {case} ({name})")
        np.testing.assert_allclose(ours_p, theirs_p, rtol=5e-4, atol=1e-5 * theirs_p.max(),
                                   err_msg=f"pdf {kind} {case} ({name})")


# every mix in rgb; the one with every lobe in the other variants
KIT_RUNS = [(k, "rgb", m) for k in MIXES for m in range(len(MIXES[k]))] + [
    (k, v, 1) for k in MIXES for v in ("mono", "spectral", "mono_polarized",
                                       "spectral_polarized")]


@pytest.mark.parametrize("kind,variant,mix", KIT_RUNS,
                         ids=[f"{k}-{v}-{m}" for k, v, m in KIT_RUNS])
def test_passes_the_test_kit(capsys, kind: str, variant: str, mix: int):
    """`rdsl test-plugin stdlib/bsdf/KIND.rdsl -p ...`: chi-square of sample() against
    pdf() (from above, and from below where it transmits), weight == eval / pdf, pdf ==
    pdf(), the albedo at most 1, finite values at grazing angles and extreme parameters."""
    from rdsl.cli import main

    args = [a for p in MIXES[kind][mix] for a in ("-p", p)]
    rc = main(["test-plugin", str(ROOT / "stdlib" / "bsdf" / f"{kind}.rdsl"), *args,
               "--variant", variant, "--samples", "100000"])
    out = capsys.readouterr().out
    assert rc == 0 and " FAIL" not in out, out
    assert out.count("chi2 sample vs pdf") >= 3 and "weight == eval/pdf" in out, out


@pytest.mark.parametrize("body,line,message", [
    ('<float name="eta" value="1.4"/><float name="specular" value="0.3"/>', 5,
     "give either 'eta' or 'specular', not both"),
    ('<float name="specular" value="20"/>', 4, "'specular' = 20 gives no valid index"),
    ('<float name="metalic" value="0.5"/>', 4,
     "unknown parameter 'metalic' of bsdf 'principled'"),
    ('<string name="roughness" value="0.5"/>', 4,
     "parameter 'roughness' of bsdf 'principled' expects a float or a texture"),
])
def test_bad_parameters_are_errors_at_their_line(tmp_path, body, line, message):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="sphere">\n'
                    '<bsdf type="principled">\n' + body.replace("/><", "/>\n<")
                    + '\n</bsdf></shape></scene>')
    with pytest.raises(CompileError) as e:
        load_scene_description(path)
    assert f"{path}:{line}:" in str(e.value) and message in str(e.value), str(e.value)


def test_specular_sets_eta_as_mitsuba(tmp_path, variant):
    """`specular` s is eta = 2 / (1 - sqrt(0.08 s)) - 1, nudged off 1 with transmission."""
    _, mi = variant
    for params in ({"specular": 0.8}, {"specular": 0.0, "spec_trans": 0.5},
                   {"eta": 1.0, "spec_trans": 0.5}, {"eta": 1.7}):
        path = _scene(tmp_path, [("principled", params)])
        ours = load_scene_description(path).shapes[0].bsdf.params["eta"]
        p = mi.traverse(mi.load_dict(_mi_dict(params)))
        theirs = float(p["eta"]) if "eta" in params else \
            2.0 / (1.0 - np.sqrt(0.08 * float(p["specular"]))) - 1.0
        assert ours == pytest.approx(theirs, rel=1e-6), params


RENDER = scene_header("0, -4, 2", "0, 0, 0.45", "0, 0, 1") + """
  <emitter type="constant"><rgb name="radiance" value="0.9, 1.0, 1.1"/></emitter>
  <shape type="rectangle">
    <transform name="to_world"><scale value="3"/></transform>
    <bsdf type="principled">
      <texture type="checkerboard" name="base_color">
        <rgb name="color0" value="0.8, 0.7, 0.2"/><rgb name="color1" value="0.1, 0.3, 0.6"/>
        <transform name="to_uv"><scale value="4"/></transform>
      </texture>
      <texture type="bitmap" name="roughness">
        <string name="filename" value="roughness.exr"/><boolean name="raw" value="true"/>
        <transform name="to_uv"><scale value="2"/></transform>
      </texture>
      <float name="metallic" value="0.4"/><float name="clearcoat" value="0.5"/>
      <float name="sheen" value="0.5"/><float name="spec_tint" value="0.3"/>
    </bsdf>
  </shape>
  <shape type="sphere">
    <point name="center" x="-0.6" y="0" z="0.5"/><float name="radius" value="0.5"/>
    <bsdf type="principled">
      <rgb name="base_color" value="0.9, 0.5, 0.4"/><float name="spec_trans" value="0.9"/>
      <float name="roughness" value="0.2"/><float name="eta" value="1.45"/>
    </bsdf>
  </shape>
  <shape type="sphere">
    <point name="center" x="0.7" y="0.2" z="0.45"/><float name="radius" value="0.45"/>
    <bsdf type="principled">
      <rgb name="base_color" value="0.3, 0.6, 0.9"/><float name="anisotropic" value="0.7"/>
      <float name="roughness" value="0.4"/><float name="flatness" value="0.6"/>
      <float name="sheen" value="1.0"/><float name="sheen_tint" value="0.8"/>
    </bsdf>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale x="0.5" y="0.4"/><rotate x="1" angle="70"/>
      <translate x="0.1" y="-0.9" z="0.45"/></transform>
    <bsdf type="principledthin">
      <rgb name="base_color" value="0.9, 0.4, 0.6"/><float name="spec_trans" value="0.5"/>
      <float name="diff_trans" value="0.8"/><float name="roughness" value="0.3"/>
      <float name="eta" value="1.3"/>
    </bsdf>
  </shape>
</scene>
"""


@pytest.mark.parametrize("variant", ["rgb", "spectral"])
def test_render_matches_mitsuba(tmp_path, variant):
    """A floor whose base colour and roughness are textures, a glass-like and a sheeny
    sphere and a thin translucent sheet (principledthin) under a constant sky, rendered by
    rdsl and by Mitsuba 3 (path, 1024 spp, 24 x 24)."""
    path = tmp_path / "principled_render.xml"
    path.write_text(RENDER)
    # (a bitmap, not a checkerboard: Mitsuba 3's checkerboard gives eval_1 its colours swapped)
    rough = np.array([[0.15, 0.7, 0.4, 0.25], [0.6, 0.2, 0.9, 0.35],
                      [0.3, 0.5, 0.1, 0.8], [0.45, 0.05, 0.65, 0.3]], np.float32)
    rdsl.write_image(tmp_path / "roughness.exr", np.repeat(rough[:, :, None], 3, axis=2))
    img, ref = render_both(path, variant, 1024)
    assert ref.mean() > 0.05
    # measured: means within 0.15%, blocks within 1.2%
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.01)
    err = block_error(img, ref)
    assert err < 0.04, err
