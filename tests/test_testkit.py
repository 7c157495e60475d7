"""``rdsl test-plugin`` (rdsl.runtime.testkit): every stdlib BSDF passes it in rgb; BSDFs
broken on purpose (a pdf off by a factor 2, sampling that disagrees with its pdf, NaN at
grazing angles, an albedo above 1) fail the check that should catch them, and only that
one; an emitter and a texture pass, and broken ones fail; wrong input is one clear message.
The numpy-only chi-square p-value is checked against scipy's.

The command runs in-process (``rdsl.cli.main``) with a reduced sample count."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from rdsl.cli import main
from rdsl.compiler.sources import source_files
from rdsl.runtime.testkit.chi2 import chi2_sf

ROOT = Path(__file__).resolve().parents[1]
BSDFS = sorted(p.stem for p in (ROOT / "stdlib" / "bsdf").glob("*.rdsl")
               if p.stem not in ("mixture", "perturbed", "common", "blend_example"))
SAMPLES = "100000"


def run(capsys, *args: str) -> tuple[int, dict[str, set[str]], str]:
    """Exit status, {result: the checks with that result}, stderr."""
    rc = main(["test-plugin", *args, "--samples", SAMPLES])
    out, err = capsys.readouterr()
    rows: dict[str, set[str]] = {}
    for line in out.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if len(cells) == 5 and cells[4] in ("PASS", "FAIL", "SKIP"):
            rows.setdefault(cells[4], set()).add(cells[0])
    return rc, rows, out + err


def test_chi2_sf_matches_scipy():
    from scipy import stats  # a declared test dependency: missing, this fails rather than skips
    for dof in (1, 2, 3, 7, 40, 399, 2500):
        for x in np.linspace(0.01, 3 * dof + 40, 60):
            want = stats.chi2.sf(x, dof)
            assert abs(chi2_sf(float(x), dof) - want) <= 1e-9 * max(want, 1e-3), (dof, x)


@pytest.mark.parametrize("name", BSDFS)
def test_stdlib_bsdf_passes(capsys, name):
    rc, rows, out = run(capsys, str(ROOT / "stdlib" / "bsdf" / f"{name}.rdsl"))
    assert rc == 0 and "FAIL" not in rows, out
    assert "chi2 sample vs pdf" in rows["PASS"], out   # Dirac lobes: their frequencies
    assert {"energy (albedo <= 1)", "finite, >= 0"} <= rows["PASS"], out


# a Lambertian BSDF to break: {eval}, {pdf} and {sample} are the bodies' last lines
LAMBERT = """import frame;
import warp;

bsdf lambert {{
    param reflectance: Texture = 0.8;

    fn eval(si: Surface, wo: Vec3) -> Spectrum {{
        let ci = cos_theta(si.wi);
        let co = cos_theta(wo);
        if ci <= 0.0 || co {eval_guard} 0.0 {{ return Spectrum(0.0); }}
        return {eval};
    }}

    fn pdf(si: Surface, wo: Vec3) -> Float {{
        if cos_theta(si.wi) <= 0.0 || cos_theta(wo) <= 0.0 {{ return 0.0; }}
        return {pdf};
    }}

    fn sample(si: Surface, u1: Float, u2: Vec2) -> BsdfSample {{
        let wo = {warp}(u2);
        let p = square_to_cosine_hemisphere_pdf(wo);
        if cos_theta(si.wi) <= 0.0 || p <= 0.0 {{
            return BsdfSample {{ wo: wo, pdf: 0.0, eta: 1.0, weight: Spectrum(0.0),
                                delta: false }};
        }}
        return BsdfSample {{ wo: wo, pdf: p, eta: 1.0, weight: {weight}, delta: false }};
    }}
}}
"""
GOOD = {"eval_guard": "<=", "eval": "reflectance(si) * (inv_pi() * co)",
        "pdf": "square_to_cosine_hemisphere_pdf(wo)", "warp": "square_to_cosine_hemisphere",
        "weight": "reflectance(si)"}
BROKEN = {
    # pdf() twice the density sample() draws from: the chi-square (pdf integrates to 2) and
    # both consistency checks (the weight is eval over pdf())
    "pdf_x2": ({"pdf": "2.0 * square_to_cosine_hemisphere_pdf(wo)"},
               {"chi2 sample vs pdf", "pdf == pdf()", "weight == eval/pdf"}),
    # uniform directions, reported with the cosine density: only the chi-square sees it
    "wrong_warp": ({"warp": "square_to_uniform_hemisphere"}, {"chi2 sample vs pdf"}),
    # eval at exactly tangent wo (cos 0 no longer returns early): 0 * inf
    "nan_grazing": ({"eval_guard": "<",
                     "eval": "reflectance(si) * (inv_pi() * co * sqrt(co) / sqrt(co))"},
                    {"finite, >= 0"}),
    # eval, pdf and weight consistent, but 1.5 times the energy
    "albedo": ({"eval": "reflectance(si) * (1.5 * inv_pi() * co)",
                "weight": "reflectance(si) * 1.5"}, {"energy (albedo <= 1)"}),
}


def lambert(tmp_path: Path, name: str, **changes: str) -> Path:
    path = tmp_path / f"{name}.rdsl"
    path.write_text(LAMBERT.format(**{**GOOD, **changes}))
    return path


def test_lambert_passes(capsys, tmp_path):
    """The unbroken one passes (so the failures below are the changes' doing)."""
    rc, rows, out = run(capsys, str(lambert(tmp_path, "lambert")))
    assert rc == 0 and "FAIL" not in rows and "SKIP" not in rows, out


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_bsdf_fails_its_check(capsys, tmp_path, case):
    changes, expected = BROKEN[case]
    rc, rows, out = run(capsys, str(lambert(tmp_path, case, **changes)))
    assert rc == 1, out
    assert rows.get("FAIL") == expected, out


def test_edited_plugin_is_recompiled(capsys, tmp_path):
    """The kernel cache keys the plugin's file: fixing it fixes the table."""
    path = lambert(tmp_path, "edited", **BROKEN["albedo"][0])
    assert run(capsys, str(path))[0] == 1
    path.write_text(LAMBERT.format(**GOOD))
    assert run(capsys, str(path))[0] == 0


def test_params_override_defaults(capsys, tmp_path):
    """-p sets a param: a reflectance of 0.6 makes the broken albedo 0.9, which passes."""
    path = lambert(tmp_path, "override", **BROKEN["albedo"][0])
    rc, _, out = run(capsys, str(path), "-p", "reflectance=0.6,0.5,0.4")
    assert rc == 0, out


def test_emitter_and_texture_pass(capsys):
    rc, rows, out = run(capsys, str(ROOT / "stdlib" / "emitter" / "area.rdsl"))
    assert rc == 0 and rows["PASS"] == {"finite, >= 0"}, out
    assert "chi2 direction sampling" in rows["SKIP"] and "eval() alone" in out
    rc, rows, out = run(capsys, str(ROOT / "stdlib" / "texture" / "checkerboard.rdsl"))
    assert rc == 0 and rows["PASS"] == {"range", "finite, >= 0"}, out
    assert "0.2 .. 0.4" in out   # the luminances of the two default colours


BROKEN_OTHERS = {
    "glow": ("""emitter glow {
    param radiance: Texture = 1.0;
    fn eval(si: Surface) -> Spectrum { return radiance(si) * (1.0 / abs(si.wi.z)); }
}
""", "finite, >= 0"),   # infinite along the surface
    "stripes": ("""texture stripes {
    param color: Texture = 0.5;
    fn eval(si: Surface) -> Spectrum { return color(si) * sin(10.0 * si.uv.x); }
    fn eval_1(si: Surface) -> Float { return 0.5; }
}
""", "range"),          # negative half the time
}


@pytest.mark.parametrize("name", list(BROKEN_OTHERS))
def test_broken_emitter_and_texture_fail(capsys, tmp_path, name):
    src, check = BROKEN_OTHERS[name]
    (tmp_path / f"{name}.rdsl").write_text(src)
    rc, rows, out = run(capsys, str(tmp_path / f"{name}.rdsl"))
    assert rc == 1 and check in rows["FAIL"], out


@pytest.mark.parametrize("content,args,message", [
    (None, ["README.md"], "expected a plugin's .rdsl file"),
    (None, ["missing.rdsl"], "missing.rdsl: error: no such file"),
    ("fn f() -> Float { return 1.0 }\n", ["bad.rdsl"], "bad.rdsl:1:"),
    ("fn f() -> Float { return 1.0; }\n", ["bad.rdsl"], "declares no plugin"),
    (LAMBERT.format(**GOOD), ["bad.rdsl", "-p", "roughness=1"], "has no param `roughness`"),
    (LAMBERT.format(**GOOD), ["bad.rdsl", "-p", "reflectance=red"],
     "is declared `Texture`; `red` is not a `Texture` value"),
    (LAMBERT.format(**GOOD), ["bad.rdsl", "--plugin", "other"], "no plugin `other`"),
    (LAMBERT.format(**GOOD), ["bad.rdsl", "--variant", "rgbx"], "unknown variant `rgbx`"),
])
def test_wrong_input_is_one_clear_message(capsys, tmp_path, monkeypatch, content, args,
                                          message):
    monkeypatch.chdir(tmp_path)
    if content is not None:
        (tmp_path / "bad.rdsl").write_text(content)
    (tmp_path / "README.md").write_text("not a plugin")
    rc = main(["test-plugin", *args])
    out, err = capsys.readouterr()
    assert rc == 1 and message in err and "Traceback" not in err + out, err


def test_unsigned_params_from_the_command_line(capsys, tmp_path):
    """`-p` sets a `UInt` param (it was refused: "is a UInt; `3` is not one") and refuses a
    negative one."""
    (tmp_path / "t.rdsl").write_text(
        "texture t {\n  param n: UInt = 1u;\n"
        "  fn eval(si: Surface) -> Spectrum { return Spectrum(Float(n) * 0.125); }\n}\n")
    rc, rows, out = run(capsys, str(tmp_path / "t.rdsl"), "-p", "n=3")
    assert rc == 0 and "0.375 .. 0.375" in out, out
    rc, rows, out = run(capsys, str(tmp_path / "t.rdsl"), "-p", "n=-3")
    assert rc == 1 and "param `n`" in out and "`-3` is not a `UInt` value" in out, out


def test_a_texture_without_eval_1_is_tested_on_eval(capsys, tmp_path):
    """eval_1 is needed only where a texture sets a Float parameter (the renderer's dispatch
    no longer calls it on every texture): test-plugin checks eval alone."""
    (tmp_path / "t.rdsl").write_text(
        "texture t {\n  fn eval(si: Surface) -> Spectrum { return Spectrum(0.25); }\n}\n")
    rc, rows, out = run(capsys, str(tmp_path / "t.rdsl"))
    assert rc == 0 and "FAIL" not in rows and rows["PASS"] == {"range"}, out
    cases = [line for line in out.splitlines() if line.startswith(("range", "finite"))]
    assert "0.25 .. 0.25" in out and not any("eval_1" in line for line in cases), out


def test_source_text_imports_next_to_its_filename(tmp_path):
    """Source text compiled under a file name imports from that file's folder, and the
    kernel cache hashes what it imports (test-plugin's harness depends on it)."""
    (tmp_path / "mine.rdsl").write_text("fn one() -> Float { return 1.0; }\n")
    files = source_files("import mine;\n", filename=str(tmp_path / "harness.rdsl"))
    assert (tmp_path / "mine.rdsl").resolve() in files
