"""Mitsuba 3's `mesh_attribute` texture: per-vertex (interpolated) and per-face attributes of
PLY meshes as a colour and as a Float parameter, also on instances, rendered against Mitsuba 3;
the attribute names against Mitsuba's PLY loader; bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _mitsuba_render import mitsuba_variant
from _plugin_scenes import check_bad, median_rmse, write_scene


def write_ply(path: Path, n: int = 4, temp: bool = False) -> Path:
    """An n x n grid of quads (two triangles each) over [-1, 1]^2 at z = 0, facing +z, with
    vertex properties r g b (vertex_color), w_x (vertex_w, one component), q_r q_g q_b
    (vertex_q_color) and with ``temp`` a property `temp` (no postfix: not an attribute), and
    face properties id_x (face_id) and k_x k_y k_z (face_k)."""
    g = np.linspace(-1, 1, n + 1)
    x, y = np.meshgrid(g, g)
    v = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    rng = np.random.default_rng(7)
    vprops = np.concatenate([rng.uniform(0.05, 0.95, (len(v), 3)),
                             rng.uniform(0.05, 0.6, (len(v), 1)),
                             rng.uniform(0, 1, (len(v), 3 + temp))], 1)
    faces = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            faces += [(a, a + 1, a + n + 2), (a, a + n + 2, a + n + 1)]
    f = np.array(faces)
    fprops = rng.uniform(0.05, 0.95, (len(f), 4))
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}",
            *[f"property float {p}" for p in ("x", "y", "z", "r", "g", "b", "w_x", "q_r",
                                               "q_g", "q_b", *["temp"] * temp)],
            f"element face {len(f)}", "property list uchar int vertex_indices",
            *[f"property float {p}" for p in ("id_x", "k_x", "k_y", "k_z")], "end_header"]
    rows = [" ".join(f"{x:.6f}" for x in r) for r in np.concatenate([v, vprops], 1)]
    rows += [f"3 {a} {b} {c} " + " ".join(f"{x:.6f}" for x in p) for (a, b, c), p in
             zip(f, fprops)]
    path.write_text("\n".join(head + rows) + "\n")
    return path


def texture(attr: str, param: str = "reflectance", extra: str = "") -> str:
    return (f'<texture type="mesh_attribute" name="{param}"><string name="name" '
            f'value="{attr}"/>{extra}</texture>')


def ply_shape(bsdf: str, transform: str = '<rotate y="1" angle="25"/>') -> str:
    return (f'<shape type="ply"><string name="filename" value="grid.ply"/><transform '
            f'name="to_world">{transform}</transform>{bsdf}</shape>')


def _check(tmp_path: Path, body: str) -> None:
    """rdsl's median RMSE within 1.2x of Mitsuba's at 32 spp, against 4096 spp."""
    write_ply(tmp_path / "grid.ply")
    mine, theirs = median_rmse(write_scene(tmp_path, body), 32)
    assert mine <= 1.2 * theirs, (mine, theirs)


@pytest.mark.parametrize("attr", ["vertex_color", "face_k", "vertex_w", "face_id"])
def test_attribute_as_reflectance_against_mitsuba(tmp_path, attr):
    """Three- and one-component vertex (interpolated) and face attributes, scaled."""
    tex = texture(attr, extra='<float name="scale" value="0.9"/>')
    _check(tmp_path, ply_shape(f'<bsdf type="diffuse">{tex}</bsdf>'))


def test_vertex_colour_spectral_against_mitsuba(tmp_path):
    """In a spectral build the corners' colours are upsampled (Mitsuba converts `*_color`
    attributes to spectral coefficients when it loads them; it reads other three-component
    attributes as coefficients as they are, which rdsl does not copy)."""
    import rdsl
    from _mitsuba_compare import mitsuba_render

    write_ply(tmp_path / "grid.ply")
    path = write_scene(tmp_path, ply_shape(f'<bsdf type="diffuse">{texture("vertex_color")}'
                                           '</bsdf>'))
    ref = mitsuba_render(path, 2048, seed=100, variant="scalar_spectral")

    def err(img: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.asarray(img, np.float64)[..., :3] - ref) ** 2)))

    scene = rdsl.load_scene(path, variant="spectral")
    mine = np.median([err(scene.render(spp=32, seed=k)) for k in range(3)])
    theirs = np.median([err(mitsuba_render(path, 32, seed=10 + k, variant="scalar_spectral"))
                        for k in range(3)])
    assert mine <= 1.2 * theirs, (mine, theirs)


def test_attribute_as_roughness_against_mitsuba(tmp_path):
    """A one-component attribute as a Float parameter (eval_1): a conductor's roughness."""
    bsdf = f'<bsdf type="roughconductor">{texture("vertex_w", "alpha")}</bsdf>'
    _check(tmp_path, ply_shape(bsdf, '<rotate x="1" angle="-35"/>'))


def test_attribute_on_instances_against_mitsuba(tmp_path):
    """The group's attribute values are stored once and read by every instance.  Mitsuba
    3.9.1 itself reads them wrongly on instances (it recomputes barycentrics from the
    world-space hit against object-space vertices: negative colours), so its reference is
    the same meshes placed as plain shapes."""
    import rdsl
    from _mitsuba_compare import mitsuba_render

    write_ply(tmp_path / "grid.ply")
    bsdf = f'<bsdf type="diffuse">{texture("vertex_color")}</bsdf>'
    places = [(20, -0.6), (-30, 0.6)]
    group = '<shape type="shapegroup" id="g">' + ply_shape(bsdf, '<scale value="0.5"/>')
    inst = "".join(f'<shape type="instance"><ref id="g"/><transform name="to_world">'
                   f'<rotate y="1" angle="{a}"/><translate x="{x}"/></transform></shape>'
                   for a, x in places)
    plain = "".join(ply_shape(bsdf, f'<scale value="0.5"/><rotate y="1" angle="{a}"/>'
                                    f'<translate x="{x}"/>') for a, x in places)
    mine_path = write_scene(tmp_path, group + "</shape>" + inst, name="instances.xml")
    ref_path = write_scene(tmp_path, plain, name="plain.xml")
    ref = mitsuba_render(ref_path, 4096, seed=100)

    def err(img: np.ndarray) -> float:
        return float(np.sqrt(np.mean((np.asarray(img, np.float64)[..., :3] - ref) ** 2)))

    scene = rdsl.load_scene(mine_path)
    mine = np.median([err(scene.render(spp=32, seed=k)) for k in range(3)])
    theirs = np.median([err(mitsuba_render(ref_path, 32, seed=10 + k)) for k in range(3)])
    assert mine <= 1.2 * theirs, (mine, theirs)


def test_attribute_names_are_mitsubas(tmp_path):
    """The attributes rdsl reads from a PLY file are those Mitsuba 3's loader makes."""
    from rdsl.runtime.scene.meshes import load_ply

    path = write_ply(tmp_path / "grid.ply", temp=True)
    with pytest.warns(UserWarning, match="'temp' has no one-letter postfix"):
        mine = load_ply(path).attributes
    assert sorted(mine) == ["face_id", "face_k", "vertex_color", "vertex_q_color", "vertex_w"]
    with mitsuba_variant("scalar_rgb") as mi:
        mesh = mi.load_dict({"type": "ply", "filename": str(path)})
        for name in [*mine, "vertex_temp", "vertex_q", "vertex_r"]:
            assert mesh.has_attribute(name) == (name in mine), name


BAD = {
    "prefix": (ply_shape(f'<bsdf type="diffuse">{texture("color")}</bsdf>'),
               "mesh_attribute: 'name' is 'color'; an attribute is named vertex_<name>"),
    "unknown": (ply_shape(f'<bsdf type="diffuse">{texture("vertex_colour")}</bsdf>'),
                ("mesh_attribute: shape 'ply' has no attribute 'vertex_colour' (its attributes: "
                "face_id, face_k, vertex_color, vertex_q_color, vertex_w)")),
    "not_a_mesh": ((f'<shape type="disk"><bsdf type="diffuse">{texture("vertex_color")}</bsdf>'
                   '</shape>'), ("mesh_attribute 'vertex_color': shape 'disk' is not a triangle "
                   "mesh and has no attributes")),
    "no_attributes": ((f'<shape type="cube"><bsdf type="diffuse">{texture("face_id")}</bsdf>'
                      '</shape>'), ("mesh_attribute: shape 'cube' has no attribute 'face_id' "
                      "(its attributes: none)")),
    "no_name": (('<shape type="cube"><bsdf type="diffuse"><texture type="mesh_attribute" '
                'name="reflectance"/></bsdf></shape>'),
                "texture 'mesh_attribute' is missing the required parameter 'name'"),
    "scale_type": (ply_shape('<bsdf type="diffuse">' + texture(
        "vertex_color", extra='<string name="scale" value="big"/>') + '</bsdf>'),
                   "parameter 'scale' of texture 'mesh_attribute' expects a float"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_mesh_attribute(tmp_path, case):
    write_ply(tmp_path / "grid.ply")
    check_bad(tmp_path, *BAD[case])
