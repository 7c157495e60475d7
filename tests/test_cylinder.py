"""Mitsuba 3's `cylinder` shape (runtime/scene/cylinder.py): its placement, normals and uvs
against Mitsuba's own, renders (textured, an area light on it, flipped normals) against
Mitsuba 3, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant
from _plugin_scenes import check_bad, median_rmse, perspective, write_scene
from rdsl.runtime.scene import load_scene_description

CYL = ('<shape type="cylinder"><point name="p0" value="-0.6, -0.3, 0.2"/>'
       '<point name="p1" value="0.5, 0.4, -0.1"/><float name="radius" value="0.35"/>'
       '{extra}</shape>')
CHECKER = ('<bsdf type="diffuse"><texture type="checkerboard" name="reflectance">'
           '<transform name="to_uv"><scale x="6" y="3"/></transform>'
           '<rgb name="color0" value="0.9, 0.2, 0.1"/><rgb name="color1" value="0.1, 0.3, 0.9"/>'
           '</texture></bsdf>')


def test_surface_matches_mitsubas_cylinder(tmp_path):
    """Rays from outside hit the mesh where Mitsuba's analytic cylinder is hit, with its
    normal and uv (to the tessellation's accuracy; away from the seam u = 0 = 1)."""
    path = tmp_path / "alone.xml"
    path.write_text(f'<scene version="3.0.0">{CYL.format(extra="")}</scene>')
    mesh = load_scene_description(path).shapes[0].mesh
    with mitsuba_variant("scalar_rgb") as mi:
        scene = mi.load_file(str(path))
        rng = np.random.default_rng(1)
        checked = 0
        for _ in range(300):
            o = rng.normal(size=3) * 2
            d = -o / np.linalg.norm(o) + rng.normal(size=3) * 0.05
            d /= np.linalg.norm(d)
            si = scene.ray_intersect(mi.Ray3f(o, d))
            if not si.is_valid():
                continue
            t, tri, b = _hit(mesh.vertices.astype(np.float64), mesh.faces, o, d)
            assert t is not None
            assert t == pytest.approx(si.t, abs=2e-3)
            f = mesh.faces[tri]
            w = np.array([1 - b[0] - b[1], b[0], b[1]])
            n = w @ mesh.normals[f].astype(np.float64)
            np.testing.assert_allclose(n / np.linalg.norm(n), np.array(si.sh_frame.n), atol=2e-3)
            uv = w @ mesh.uvs[f].astype(np.float64)
            if 0.01 < si.uv[0] < 0.99:
                np.testing.assert_allclose(uv, np.array(si.uv), atol=2e-3)
            checked += 1
    assert checked > 50


def _hit(v: np.ndarray, f: np.ndarray, o: np.ndarray, d: np.ndarray):
    """The nearest triangle of (v, f) along o + t d: (t, triangle, barycentrics of 1, 2)."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    w = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 1e-6)
    if not hit.any():
        return None, None, None
    k = int(np.argmin(np.where(hit, t, np.inf)))
    return t[k], k, (u[k], w[k])


def _check(path) -> None:
    """rdsl's median RMSE within 1.2x of Mitsuba's at 32 spp, against 4096 spp."""
    mine, theirs = median_rmse(path, 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


def test_textured_cylinder_against_mitsuba(tmp_path):
    _check(write_scene(tmp_path, CYL.format(extra=CHECKER)))


@pytest.mark.parametrize("flip", [False, True])
def test_area_light_on_a_cylinder_against_mitsuba(tmp_path, flip):
    """An emitting tube lights the wall (sampled by area); flipped, it emits inwards."""
    extra = (('<boolean name="flip_normals" value="true"/>' if flip else "")
             + '<emitter type="area"><rgb name="radiance" value="4, 3, 2"/></emitter>')
    body = CYL.format(extra=extra).replace('value="0.35"', 'value="0.15"')
    sensor = perspective(origin="0.3, 2.5, 3.5", fov=45)
    _check(write_scene(tmp_path, body, sensor=sensor, max_depth=3))


BAD = {
    "radius": ('<shape type="cylinder"><float name="radius" value="0"/></shape>',
               "cylinder: 'radius' must be positive"),
    "same_points": ('<shape type="cylinder"><point name="p1" value="0, 0, 0"/></shape>',
                    "'p0' and 'p1' are the same point"),
    "radius_type": ('<shape type="cylinder"><string name="radius" value="big"/></shape>',
                    "parameter 'radius' of shape 'cylinder' expects a float, got <string>"),
    "p0_type": ('<shape type="cylinder"><float name="p0" value="1"/></shape>',
                "parameter 'p0' of shape 'cylinder' expects a point, got <float>"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_cylinder(tmp_path, case):
    check_bad(tmp_path, *BAD[case])
