"""Mitsuba 3's `linearcurve` and `bsplinecurve` shapes (runtime/scene/curves.py, traced by
runtime/embree_curves.py, shaded by stdlib/render/geometry.rdsl): ray hits and surface
interactions against Mitsuba's, ray by ray; renders (textured, anisotropic, bump-mapped)
against Mitsuba 3; bad curve files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant
from _plugin_scenes import check_bad, median_rmse, write_scene
from rdsl.runtime.scene import SceneError, load_scene_description

# two linear curves (one bent, one straight) and one B-spline of five points (two segments)
LINEAR = """-1.0 0.0 0.0 0.2
0.0 0.3 0.2 0.3
1.0 0.0 0.5 0.1

-1 -1 0 0.1
1 -1 0.3 0.15
"""
BSPLINE = """-1.0 0.0 0.0 0.2
-0.5 0.5 0.2 0.3
0.5 0.3 0.2 0.3
1.0 0.0 0.5 0.1
1.5 -0.5 0.5 0.2
"""
# the B-spline moved and turned (to_world moves the points, not the radii)
MOVED = ('<transform name="to_world"><rotate y="1" angle="25"/><scale value="0.8"/>'
         '<translate y="-0.5" z="0.3"/></transform>')


def curve_files(folder: Path) -> None:
    (folder / "lin.txt").write_text(LINEAR)
    (folder / "bsp.txt").write_text(BSPLINE)


def shapes(linear_bsdf: str = "", bspline_bsdf: str = "") -> str:
    return (f'<shape type="linearcurve"><string name="filename" value="lin.txt"/>{linear_bsdf}'
            f'</shape><shape type="bsplinecurve"><string name="filename" value="bsp.txt"/>'
            f'{MOVED}{bspline_bsdf}</shape>')


def test_hits_match_mitsubas(tmp_path):
    """Embree's round curves, set up by rdsl, are hit where Mitsuba's are, at the same
    distance; rays from inside a tube pass out of it (back faces are culled, as in
    Mitsuba), for intersection and occlusion queries alike."""
    from rdsl.runtime.embree import EmbreeScene
    from rdsl.runtime.embree_curves import EmbreeCurves

    curve_files(tmp_path)
    path = write_scene(tmp_path, shapes(), room=False)
    desc = load_scene_description(path)
    rng = np.random.default_rng(3)
    with mitsuba_variant("scalar_rgb") as mi:
        for shape in desc.shapes:
            c = shape.curves
            mine = EmbreeScene([EmbreeCurves(c.kind, c.points, c.segments)])
            theirs = mi.load_dict({"type": "scene", "c": {
                "type": shape.type, "filename": shape.params["filename"],
                "to_world": mi.ScalarTransform4f(shape.params["to_world"])}})
            # rays at the curves from afar, and rays from points on the curves' axes
            axis = c.points[rng.integers(len(c.points), size=200), :3].astype(np.float64)
            o = np.vstack([rng.normal(size=(1500, 3)) * 3, axis])
            target = rng.normal(size=(len(o), 3)) * 0.5 + c.points[:, :3].mean(axis=0)
            d = target - o
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            hits, occluded = mine.intersect(o, d), mine.occluded(o, d)
            found = np.array([theirs.ray_intersect(mi.Ray3f(o[i], d[i])).t
                              for i in range(len(o))])
            agree = hits["hit"] == np.isfinite(found)
            assert agree.mean() > 0.998, (shape.type, agree.mean())
            assert np.array_equal(occluded, hits["hit"])
            both = hits["hit"] & np.isfinite(found)
            assert both.sum() > 200
            np.testing.assert_allclose(hits["t"][both], found[both], atol=1e-4)


PROBE = """
import render.geometry;
struct Out { p: Vec3, n: Vec3, s: Vec3, t: Vec3, wi: Vec3, uv: Vec2, dp_du: Vec3, dp_dv: Vec3,
             shape: Int, valid: Bool }
fn probe(o: Vec3, d: Vec3, P: [Float], N: [Float], UV: [Float], F: [Int], G: [Int]) -> Out {
    let ray = Ray { o: o, d: d, tmax: infinity() };
    let h = trace(ray);
    let z = Vec3(0.0, 0.0, 0.0);
    if !h.valid {
        return Out { p: z, n: z, s: z, t: z, wi: z, uv: Vec2(0.0, 0.0), dp_du: z, dp_dv: z,
                     shape: -1, valid: false };
    }
    let it = interaction(ray, h, P, N, UV, F, G);
    return Out { p: it.si.p, n: it.frame.n, s: it.frame.s, t: it.frame.t, wi: it.si.wi,
                 uv: it.si.uv, dp_du: it.dp_du, dp_dv: it.dp_dv, shape: it.shape,
                 valid: true };
}
"""


@pytest.mark.parametrize("kind", ["linearcurve", "bsplinecurve"])
def test_surface_matches_mitsubas(tmp_path, kind):
    """Ray by ray, geometry.rdsl's interaction on a curve is Mitsuba's: the point, the
    shading frame (normal and tangent), uv (u around, v along all segments) and dp/du,
    dp/dv (zero on Mitsuba 3.9's linear curves; from the Frenet frame on B-splines)."""
    import rdsl
    from rdsl.core.scene_spec import SceneSpec
    from rdsl.runtime.render.renderer import load_scene

    curve_files(tmp_path)
    path = tmp_path / "alone.xml"
    path.write_text(f'<scene version="3.0.0"><shape type="{kind}"><string name="filename" '
                    f'value="{"lin" if kind == "linearcurve" else "bsp"}.txt"/>{MOVED}'
                    '</shape></scene>')
    scene = load_scene(path)
    mod = rdsl.jit(PROBE, scene=SceneSpec())
    mod.bind_scene(scene.embree)
    rng = np.random.default_rng(0)
    o = (rng.normal(size=(2000, 3)) * 3).astype(np.float32)
    d = rng.normal(size=(2000, 3)) * 0.5 + [0.2, -0.3, 0.3] - o
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    b = scene.buffers
    out = {k: np.asarray(v) for k, v in mod.probe(o, d, b.P, b.N, b.UV, b.F, b.G).items()}
    checked = 0
    with mitsuba_variant("scalar_rgb") as mi:
        theirs = mi.load_file(str(path))
        for i in np.flatnonzero(out["valid"]):
            si = theirs.ray_intersect(mi.Ray3f(o[i].astype(float), d[i].astype(float)))
            if not si.is_valid():
                continue
            for mine, ref in ((out["p"][i], si.p), (out["n"][i], si.sh_frame.n),
                              (out["s"][i], si.sh_frame.s)):
                np.testing.assert_allclose(mine, np.array(ref), atol=2e-4)
            du = abs(out["uv"][i][0] - si.uv[0])
            assert min(du, 1 - du) < 1e-4 and abs(out["uv"][i][1] - si.uv[1]) < 1e-4
            for k in ("dp_du", "dp_dv"):
                ref = np.array(getattr(si, k))
                np.testing.assert_allclose(out[k][i], ref, atol=1e-4 * (1 + np.linalg.norm(ref)))
            checked += 1
    assert checked > 500


def _check(path: Path) -> None:
    """rdsl's median RMSE within 1.2x of Mitsuba's at 32 spp, against 4096 spp."""
    mine, theirs = median_rmse(path, 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


CHECKER = ('<bsdf type="diffuse"><texture type="checkerboard" name="reflectance">'
           '<transform name="to_uv"><scale x="4" y="6"/></transform>'
           '<rgb name="color0" value="0.9, 0.2, 0.1"/><rgb name="color1" value="0.1, 0.3, 0.9"/>'
           '</texture></bsdf>')
ANISO = ('<bsdf type="roughconductor"><float name="alpha_u" value="0.05"/>'
         '<float name="alpha_v" value="0.4"/></bsdf>')
BUMPS = ('<bsdf type="bumpmap"><texture type="bitmap" name="map"><string name="filename" '
         'value="bumps.png"/><boolean name="raw" value="true"/></texture>'
         '<float name="scale" value="0.2"/><bsdf type="diffuse"/></bsdf>')


def test_textured_curves_against_mitsuba(tmp_path):
    """Both kinds textured through their uvs, the B-spline placed by to_world."""
    curve_files(tmp_path)
    _check(write_scene(tmp_path, shapes(CHECKER, CHECKER)))


def test_anisotropic_and_bumpy_curves_against_mitsuba(tmp_path):
    """An anisotropic conductor (its frame follows dp/du) on the linear curves and a
    bump map (which reads dp/du and dp/dv at Mitsuba's lengths) on the B-spline."""
    from PIL import Image

    curve_files(tmp_path)
    y, x = np.mgrid[0:64, 0:64] / 64
    bumps = 0.5 + 0.5 * np.sin(6 * np.pi * x) * np.cos(4 * np.pi * y)
    Image.fromarray((bumps * 255).astype(np.uint8)).save(tmp_path / "bumps.png")
    _check(write_scene(tmp_path, shapes(ANISO, BUMPS)))


# -- bad input


def _load_error(tmp_path: Path, kind: str, text: str | None) -> str:
    if text is not None:
        (tmp_path / "c.txt").write_text(text)
    path = tmp_path / "bad.xml"
    path.write_text(f'<scene version="3.0.0">\n  <shape type="{kind}">\n'
                    f'    <string name="filename" value="c.txt"/>\n  </shape>\n</scene>\n')
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    return str(exc.value)


@pytest.mark.parametrize(("kind", "text", "line", "message"), [
    ("linearcurve", "0 0 0 0.1\n1 0 0 oops\n", 2, "expected a control point 'x y z radius'"),
    ("linearcurve", "0 0 0 0.1\n1 0 0\n", 2, "(4 numbers), got 3 fields"),
    ("linearcurve", "0 0 0 0.1\n1 0 0 -1\n", 2, "radius must not be negative"),
    ("linearcurve", "0 0 0 0.1\n1 0 0 inf\n", 2, "is not finite"),
    ("linearcurve", "0 0 0 0.1\n1 0 0 0.1\n\n\n2 0 0 0.1\n", 5,
     "the curve starting at line 5 has 1 control point; a linearcurve needs at least 2"),
    ("bsplinecurve", "0 0 0 0.1\n1 0 0 0.1\n2 1 0 0.1\n", 3,
     "the curve starting at line 1 has 3 control points; a bsplinecurve needs at least 4"),
])
def test_bad_curve_file(tmp_path, kind, text, line, message):
    """A malformed line or a curve of too few points: the curve file and the line."""
    err = _load_error(tmp_path, kind, text)
    assert err.startswith(f"{tmp_path / 'c.txt'}:{line}:"), err
    assert message in err and "cannot load curve file 'c.txt'" in err, err


def test_empty_and_missing_curve_files(tmp_path):
    err = _load_error(tmp_path, "bsplinecurve", "\n\n")
    assert "the file holds no control points" in err and str(tmp_path / "c.txt") in err, err
    (tmp_path / "c.txt").unlink()
    err = _load_error(tmp_path, "linearcurve", None)
    assert err.startswith(f"{tmp_path / 'bad.xml'}:3:"), err
    assert "curve file 'c.txt' not found" in err, err


BAD = {
    "emitter": (('<shape type="linearcurve"><string name="filename" value="c.txt"/>'
                 '<emitter type="area"/></shape>'),
                ("linearcurve: cannot hold emitter 'area' (a point on a curve cannot be "
                 "sampled")),
    "no_file": ('<shape type="bsplinecurve"/>',
                "shape 'bsplinecurve' is missing the required parameter 'filename'"),
    "shapegroup": (('<shape type="shapegroup"><shape type="linearcurve">'
                    '<string name="filename" value="c.txt"/></shape></shape>'),
                   "shapegroup: cannot hold a nested 'linearcurve' shape"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_curve_shape(tmp_path, case):
    (tmp_path / "c.txt").write_text(LINEAR)
    check_bad(tmp_path, *BAD[case])


def test_curve_file_layout(tmp_path):
    """Tabs, CRLF line ends and runs of blank lines read as Mitsuba reads them: a blank line
    ends a curve; each curve's segments start at its points but the last (1 or 3)."""
    from rdsl.runtime.scene.curves import read_curves

    path = tmp_path / "c.txt"
    path.write_text("\r\n0\t0 0 0.1\r\n1 0 0 0.1\r\n\r\n\r\n  2 0 0 0.2\r\n3 0 0 0.2\r\n"
                    "4 1 0 0.2\r\n5 1 1 0.2\r\n\r\n")
    linear = read_curves("linearcurve", path)
    assert linear.points.shape == (6, 4)
    assert linear.points[2].tolist() == pytest.approx([2, 0, 0, 0.2])
    assert linear.segments.tolist() == [0, 2, 3, 4]
    with pytest.raises(ValueError, match="a bsplinecurve needs at least 4"):
        read_curves("bsplinecurve", path)
    path.write_text("0 0 0 1\n1 0 0 1\n2 1 0 1\n3 1 1 1\n4 0 0 1\n")
    assert read_curves("bsplinecurve", path).segments.tolist() == [0, 1]
