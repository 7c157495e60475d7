"""Mitsuba 3's named conductors (`material="W"`, stdlib/data/ior, tools/gen_conductor_ior.py)
against Mitsuba 3 itself: the same materials are accepted, and a scene's `conductor` and
`roughconductor` made of them give Mitsuba's values in rgb (the spectra projected to sRGB as
Mitsuba's `ior_from_file` does) and in spectral (the tables sampled at each row's
wavelengths, zero beyond a table's last knot as Mitsuba's `irregular` spectrum)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _bsdf_harness import SceneBsdfs
from _mitsuba_render import mitsuba_variant
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.scene.loader import load_scene_description
from rdsl.runtime.scene.spectra import conductor_materials

f32 = np.float32
# a spread of tables: AlSb ends at 590 nm, Li at 751 nm, TiN at 827 nm (Mitsuba's spectra
# are zero beyond them), Hg is a liquid metal, a-C amorphous carbon
MATERIALS = ["W", "a-C", "Cr", "TiN", "Hg", "Au", "AlSb", "Li", "Cu2O_palik", "none"]
ROUGH = {"alpha": 0.3, "distribution": "ggx"}


@pytest.fixture(params=["rgb", "spectral"])
def variant(request) -> Iterator[tuple[str, Any]]:
    with mitsuba_variant(f"scalar_{request.param}") as mi:
        yield request.param, mi


def _scene(tmp_path: Path) -> Path:
    """One sphere per material: a smooth then a rough conductor of each."""
    shapes = []
    for m in MATERIALS:
        mat = f'<string name="material" value="{m}"/>'
        shapes.append(f'<shape type="sphere"><bsdf type="conductor">{mat}</bsdf></shape>')
        shapes.append('<shape type="sphere"><bsdf type="roughconductor">'
                      f'{mat}<float name="alpha" value="{ROUGH["alpha"]}"/>'
                      f'<string name="distribution" value="{ROUGH["distribution"]}"/>'
                      '</bsdf></shape>')
    path = tmp_path / "conductors.xml"
    path.write_text('<scene version="3.0.0">' + "".join(shapes) + "</scene>")
    return path


def _directions(n: int, seed: int) -> np.ndarray:
    """n directions of the upper hemisphere, uniformly in solid angle."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.02, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).astype(f32)


def _surfaces(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(np.array([0, 0, 1], f32), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


def _mi_si(mi: Any, wi: np.ndarray, lam: np.ndarray | None) -> Any:
    si = mi.SurfaceInteraction3f()
    si.p, si.n, si.sh_frame = [0, 0, 0], [0, 0, 1], mi.Frame3f([0, 0, 1])
    si.wi = [float(x) for x in wi]
    if lam is not None:
        si.wavelengths = [float(x) for x in lam]
    return si


def test_every_mitsuba_material_is_accepted():
    """The names are Mitsuba's: the tables its wheel ships (one per `data/ior/NAME.eta.spd`),
    and `none`."""
    mi = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    theirs = {p.name[: -len(".eta.spd")]
              for p in (Path(mi.__file__).parent / "data" / "ior").glob("*.eta.spd")}
    assert set(conductor_materials()) == theirs | {"none"}
    assert len(theirs) >= 40


def test_unknown_material_is_an_error_at_its_line(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="sphere">\n<bsdf type="conductor">\n'
                    '    <string name="material" value="Adamantium"/>\n</bsdf></shape></scene>')
    with pytest.raises(CompileError) as e:
        load_scene_description(path)
    msg = str(e.value)
    assert f"{path}:4:" in msg and "'Adamantium' is unknown" in msg
    assert all(name in msg for name in ("a-C", "W", "Cr", "TiN", "Hg", "none"))


def test_named_conductors_match_mitsuba(tmp_path, variant):
    """sample() of the smooth conductor (its weight is the Fresnel term) and eval() of the
    rough one, at 64 directions each, against Mitsuba's, material by material."""
    name, mi = variant
    bsdfs = SceneBsdfs(_scene(tmp_path), name)
    n = 64
    wi, wo = _directions(n, 1), _directions(n, 2)
    ctx = mi.BSDFContext()
    for i, material in enumerate(MATERIALS):
        smooth, rough = bsdfs[2 * i], bsdfs[2 * i + 1]
        lam = smooth.wavelengths(n)
        ours_f = smooth.sample(_surfaces(wi), np.full(n, 0.5, f32), np.full((n, 2), 0.5, f32))
        ours_r = rough.eval(_surfaces(wi), wo)
        mi_s = mi.load_dict({"type": "conductor", "material": material})
        mi_r = mi.load_dict({"type": "roughconductor", "material": material, **ROUGH})
        theirs_f, theirs_r = [], []
        for j in range(n):
            si = _mi_si(mi, wi[j], None if lam is None else lam[j])
            _, w = mi_s.sample(ctx, si, 0.5, [0.5, 0.5])
            theirs_f.append(np.array(w, np.float64).ravel())
            theirs_r.append(np.array(mi_r.eval(ctx, si, [float(x) for x in wo[j]]),
                                     np.float64).ravel())
        for ours, theirs in ((ours_f["weight"], theirs_f), (ours_r, theirs_r)):
            ours = np.asarray(ours, np.float64).reshape(n, -1)
            theirs = np.array(theirs)
            assert ours.shape == theirs.shape
            np.testing.assert_allclose(ours, theirs, rtol=2e-4, atol=2e-5 * theirs.max(),
                                       err_msg=f"{material} ({name})")


def test_committed_tables_are_the_generators_output(tmp_path):
    """stdlib/data/ior is what tools/gen_conductor_ior.py makes of Mitsuba's data/ior, so the
    data cannot drift from its documented source; a malformed source row is refused."""
    from rdsl.tools import gen_conductor_ior as gen

    pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    names = gen.generate(gen.default_source(), tmp_path / "out")
    assert len(names) >= 40 and "W" in names and "a-C" in names
    committed = {p.name for p in gen.OUT.glob("*.spd")}
    assert committed == {p.name for p in (tmp_path / "out").glob("*.spd")}
    for name in committed:
        assert (gen.OUT / name).read_text() == (tmp_path / "out" / name).read_text(), name
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "X.eta.spd").write_text("# header\n400 1.0\n390 1.1\n")
    (bad / "X.k.spd").write_text("400 1.0\n500 1.1\n")
    with pytest.raises(SystemExit, match="X.eta.spd:3: not an increasing"):
        gen.generate(bad, tmp_path / "out2")
