"""``rdsl stress`` (rdsl.runtime.testkit.stress): a few stdlib plugins swept with ``--fast``
in two variants give a full table of zero counts and exit 0; a Lambertian BSDF broken on
purpose (NaN at grazing angles, negative values, an albedo above 1, a pdf off by 2) exits 1
with the count of its own problem non-zero; a NaN or Inf parameter is counted apart and does
not fail; wrong input is one clear message.  In-process (``rdsl.cli.main``)."""

from __future__ import annotations

import re

import pytest
from rdsl.cli import main
from test_testkit import BROKEN, GOOD, LAMBERT  # the test kit's Lambertian BSDF to break

COLUMNS = ["plugin", "variant", "cases", "NaN", "Inf", "negative", "energy gain", "mismatch",
           "NaN/Inf params (propagated, garbage)"]
COUNTS = COLUMNS[3:8]


def stress(capsys, *args: str) -> tuple[int, list[dict[str, str]], str]:
    """Exit status, the table's rows as {column: cell}, the whole output."""
    rc = main(["stress", "--fast", *args])
    out, err = capsys.readouterr()
    lines = out.splitlines()
    head = re.split(r"\s{2,}", lines[0].strip())
    assert head == COLUMNS, out + err
    rows = []
    for line in lines[2:]:
        cells = re.split(r"\s{2,}", line.strip())
        if len(cells) != len(COLUMNS):
            break
        rows.append(dict(zip(COLUMNS, cells)))
    return rc, rows, out + err


def test_stdlib_plugins_have_zero_counts(capsys):
    plugins = ["conductor", "dielectric", "diffuse", "area", "checkerboard"]  # stdlib order
    rc, rows, out = stress(capsys, "--variants", "rgb,spectral", "--plugins", ",".join(plugins))
    assert rc == 0 and out.rstrip().endswith("all counts zero"), out
    assert [(r["plugin"], r["variant"]) for r in rows] == \
        [(p, v) for p in plugins for v in ("rgb", "spectral")], out
    for r in rows:
        assert int(r["cases"]) > 0 and all(r[c] == "0" for c in COUNTS), out
    # diffuse: reflectance NaN and Inf, two cases; both propagate, neither is garbage
    diffuse = rows[4]["NaN/Inf params (propagated, garbage)"]
    assert diffuse == "2 (2, 0)", out


NEGATIVE = {"eval": "reflectance(si) * (inv_pi() * (co - 0.2))",
            "weight": "reflectance(si) * (1.0 - 0.2 / cos_theta(wo))"}


@pytest.mark.parametrize("case,column", [("nan_grazing", "NaN"), ("negative", "negative"),
                                         ("albedo", "energy gain"), ("pdf_x2", "mismatch")])
def test_broken_plugin_is_caught(capsys, tmp_path, case, column):
    changes = NEGATIVE if case == "negative" else BROKEN[case][0]
    path = tmp_path / f"{case}.rdsl"
    path.write_text(LAMBERT.format(**{**GOOD, **changes}))
    rc, rows, out = stress(capsys, str(path), "--variants", "rgb")
    assert rc == 1 and out.rstrip().endswith("FAIL"), out
    assert len(rows) == 1 and rows[0]["plugin"] == "lambert", out
    assert int(rows[0][column]) > 0, out


def test_good_plugin_passes(capsys, tmp_path):
    path = tmp_path / "good.rdsl"
    path.write_text(LAMBERT.format(**GOOD))
    rc, rows, out = stress(capsys, str(path), "--variants", "mono")
    assert rc == 0 and all(rows[0][c] == "0" for c in COUNTS), out


@pytest.mark.parametrize("args,message", [
    (["missing.rdsl"], "no such file"),
    (["--plugins", "nosuch"], "--plugins: no plugin nosuch"),
    (["--variants", "nosuch", "--plugins", "diffuse"], "nosuch"),
])
def test_wrong_input_is_one_clear_message(capsys, tmp_path, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    rc = main(["stress", "--fast", *args])
    out, err = capsys.readouterr()
    assert rc != 0 and message in out + err and "Traceback" not in out + err, out + err


@pytest.mark.parametrize("variant", ["rgb", "mono_polarized"])
def test_conductor_with_index_zero_is_a_mirror(variant):
    """What the sweep found: eta = k = 0 was NaN (0 / 0, a division by 0 in the polarized
    Fresnel term). Its limit n -> 0 reflects everything: |r_s| = |r_p| = 1 at every angle."""
    import numpy as np
    from rdsl.runtime.testkit.common import surface, tile
    from rdsl.runtime.testkit.harness import Harness

    h = Harness("conductor", variant)
    for c in (1.0, 0.5, 1e-3):
        wi = np.array([np.sqrt(1 - c * c), 0, c], np.float32)
        bs = h.sample(surface(tile(wi, 4)), np.full(4, 0.5, np.float32),
                      np.full((4, 2), 0.5, np.float32), eta=0.0, k=0.0)
        assert np.allclose(np.asarray(bs["weight"]), 1.0, atol=1e-5), (variant, c, bs["weight"])
