"""Mitsuba 3 scene loading, the shapes: analytic shapes, OBJ, PLY and Mitsuba's serialized
meshes, vertex normals (tests/test_scene_parser.py: the XML, errors and spectra)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from rdsl.runtime.scene import meshes
from test_scene_parser import load, scene, write

# ---------------------------------------------------------------------------------------
# Meshes

def _outward(mesh: meshes.Mesh, center=(0.0, 0.0, 0.0)) -> bool:
    v = mesh.vertices.astype(float)
    p = v[mesh.faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return bool((np.einsum("ij,ij->i", n, p.mean(axis=1) - center) > 0).all())


def test_analytic_shapes(tmp_path: Path) -> None:
    path = scene(tmp_path, '<shape type="sphere"><point name="center" value="1, 2, 3"/>',
                 '<float name="radius" value="0.5"/></shape>',
                 '<shape type="cube"><boolean name="flip_normals" value="true"/></shape>',
                 '<shape type="disk"/>',
                 '<shape type="cube"><boolean name="face_normals" value="true"/></shape>')
    sph, cube, disk, faceted = load(path).shapes
    r = np.linalg.norm(sph.mesh.vertices - [1, 2, 3], axis=1)
    np.testing.assert_allclose(r, 0.5, atol=1e-6)
    assert _outward(sph.mesh, (1, 2, 3))
    n_dot = np.einsum("ij,ij->i", sph.mesh.normals, (sph.mesh.vertices - [1, 2, 3]) / 0.5)
    assert (n_dot > 0.999).all()
    assert len(cube.mesh.faces) == 12 and not _outward(cube.mesh)  # flipped inwards
    v = cube.mesh.vertices[cube.mesh.faces]
    assert (np.einsum("ij,ij->i", cube.mesh.normals[cube.mesh.faces[:, 0]],
                      v.mean(axis=1)) < 0).all()
    assert np.abs(cube.mesh.vertices).max() == 1.0
    assert disk.mesh.vertices[:, 2].max() == 0 and len(disk.mesh.faces) >= 64
    np.testing.assert_allclose(np.linalg.norm(disk.mesh.vertices, axis=1).max(), 1.0)
    assert faceted.mesh.normals is None and faceted.mesh.face_normals


def test_cube_is_mitsubas() -> None:
    """The cube's vertices, uvs, normals and triangles are Mitsuba 3's own, so a texture
    lands on each face as in Mitsuba (the uvs were laid out differently: a textured cube
    differed, RMSE 11x Mitsuba's in tests/compat)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    theirs = mi.traverse(mi.load_dict({"type": "cube"}))
    mine = meshes.cube()
    for key, ours in (("vertex_positions", mine.vertices), ("vertex_texcoords", mine.uvs),
                      ("vertex_normals", mine.normals), ("faces", mine.faces)):
        np.testing.assert_array_equal(np.array(theirs[key]).reshape(ours.shape), ours,
                                      err_msg=key)


def test_obj_loader(tmp_path: Path) -> None:
    p = write(tmp_path / "m.obj", "# a quad and a pentagon", "o thing",
              "v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0",
              "vt 0 0", "vt 1 0", "vt 1 1", "vt 0 1", "vn 0 0 1",
              "f 1/1/1 2/2/1 3/3/1 4/4/1",
              "v 0 0 1", "v 1 0 1", "v 2 1 1", "v 1 2 1", "v 0 1 1",
              "usemtl x", "f -5 -4 -3 -2 -1")
    m = meshes.load_obj(p)
    assert m.faces.shape == (2 + 3, 3) and m.faces.dtype == np.uint32
    assert m.vertices.shape == (9, 3) and m.vertices.dtype == np.float32
    assert m.normals is None  # the pentagon has no vn: Mitsuba recomputes them
    np.testing.assert_allclose(m.uvs[:4], [[0, 1], [1, 1], [1, 0], [0, 0]])  # v flipped
    np.testing.assert_allclose(m.vertices[m.faces[2]], [[0, 0, 1], [1, 0, 1], [2, 1, 1]])
    quad = meshes.load_obj(write(tmp_path / "q.obj", "v 0 0 0", "v 1 0 0", "v 1 1 0",
                                 "vn 0 0 1", "f 1//1 2//1 3//1"))
    np.testing.assert_allclose(quad.normals, np.tile([0, 0, 1], (3, 1)))
    with pytest.raises(meshes.MeshError, match="index 0"):
        meshes.load_obj(write(tmp_path / "z.obj", "v 0 0 0", "f 0 1 1"))


def _ply(tmp_path: Path, fmt: str, name: str) -> Path:
    v = np.array([[0, 0, 0, 0, 0], [1, 0, 0, 1, 0], [1, 1, 0, 1, 1], [0, 1, 0, 0, 1]], "f4")
    header = ["ply", f"format {fmt} 1.0", "comment made by a test", "element vertex 4",
              "property float x", "property float y", "property float z",
              "property float s", "property float t", "element face 2",
              "property list uchar int vertex_indices", "end_header"]
    path = tmp_path / name
    if fmt == "ascii":
        body = [" ".join(str(x) for x in row) for row in v] + ["3 0 1 2", "3 0 2 3"]
        write(path, *header, *body)
        return path
    o = "<" if fmt == "binary_little_endian" else ">"
    data = v.astype(o + "f4").tobytes()
    for f in ([0, 1, 2], [0, 2, 3]):
        data += struct.pack(o + "B3i", 3, *f)
    path.write_bytes(("\n".join(header) + "\n").encode() + data)
    return path


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_loader(tmp_path: Path, fmt: str) -> None:
    m = meshes.load_ply(_ply(tmp_path, fmt, f"{fmt}.ply"))
    assert m.vertices.shape == (4, 3) and m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_allclose(m.uvs[2], [1, 1])
    assert m.normals is None


def test_ply_polygons_and_normals(tmp_path: Path) -> None:
    p = write(tmp_path / "quad.ply", "ply", "format ascii 1.0", "element vertex 4",
              "property double x", "property double y", "property double z",
              "property float nx", "property float ny", "property float nz",
              "element face 1", "property list uchar uint vertex_index", "end_header",
              "0 0 0 0 0 1", "1 0 0 0 0 1", "1 1 0 0 0 1", "0 1 0 0 0 1", "4 0 1 2 3")
    m = meshes.load_ply(p)
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    np.testing.assert_allclose(m.normals[:, 2], 1)
    path = scene(tmp_path, '<shape type="ply"><string name="filename" value="quad.ply"/>',
                 '<transform name="to_world"><translate z="5"/></transform></shape>')
    sh = load(path).shapes[0]
    np.testing.assert_allclose(sh.mesh.vertices[:, 2], 5)


def write_serialized(path: Path, parts: list[dict], version: int = 4,
                     double: bool = False) -> Path:
    """Our own writer of Mitsuba's .serialized format (per Mitsuba 3's documentation)."""
    out, offsets = bytearray(), []
    ft = "<f8" if double else "<f4"
    for part in parts:
        offsets.append(len(out))
        flags = 0x2000 if double else 0x1000
        flags |= (0x0001 if "n" in part else 0) | (0x0002 if "uv" in part else 0)
        flags |= 0x0008 if "c" in part else 0
        payload = struct.pack("<I", flags)
        if version == 4:
            payload += part.get("name", "mesh").encode() + b"\0"
        payload += struct.pack("<QQ", len(part["v"]), len(part["f"]))
        for key in ("v", "n", "uv", "c"):
            if key in part:
                payload += np.asarray(part[key], ft).tobytes()
        payload += np.asarray(part["f"], "<u4").tobytes()
        out += struct.pack("<HH", 0x041C, version) + zlib.compress(payload)
    code = "Q" if version == 4 else "I"
    out += struct.pack(f"<{len(offsets)}{code}", *offsets) + struct.pack("<I", len(offsets))
    path.write_bytes(bytes(out))
    return path


def test_serialized_loader(tmp_path: Path) -> None:
    tri = {"v": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "f": [[0, 1, 2]], "name": "tri"}
    quad = {"v": [[0, 0, 2], [1, 0, 2], [1, 1, 2], [0, 1, 2]], "f": [[0, 1, 2], [0, 2, 3]],
            "n": [[0, 0, 1]] * 4, "uv": [[0, 0], [1, 0], [1, 1], [0, 1]],
            "c": [[1, 0, 0]] * 4}
    for version in (3, 4):
        for double in (False, True):
            p = write_serialized(tmp_path / f"m{version}{double}.serialized", [tri, quad],
                                 version, double)
            a = meshes.load_serialized(p, 0)
            assert a.faces.tolist() == [[0, 1, 2]] and a.normals is None and a.uvs is None
            b = meshes.load_serialized(p, 1)
            assert b.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
            np.testing.assert_allclose(b.vertices[:, 2], 2)
            np.testing.assert_allclose(b.uvs[2], [1, 1])
            np.testing.assert_allclose(b.normals, quad["n"])
            with pytest.raises(meshes.MeshError, match="shape_index 2 is out of range"):
                meshes.load_serialized(p, 2)
    path = scene(tmp_path, '<shape type="serialized">',
                 '<string name="filename" value="m4False.serialized"/>',
                 '<integer name="shape_index" value="1"/>',
                 '<boolean name="face_normals" value="true"/></shape>')
    sh = load(path).shapes[0]
    assert len(sh.mesh.faces) == 2 and sh.mesh.normals is None


def test_vertex_normals_and_flip(tmp_path: Path) -> None:
    write(tmp_path / "t.obj", "v 0 0 0", "v 1 0 0", "v 0 1 0", "f 1 2 3")
    path = scene(tmp_path, '<shape type="obj"><string name="filename" value="t.obj"/>',
                 '<boolean name="flip_normals" value="true"/></shape>',
                 '<shape type="obj"><string name="filename" value="t.obj"/></shape>')
    flipped, plain = load(path).shapes
    np.testing.assert_allclose(plain.mesh.normals, np.tile([0, 0, 1], (3, 1)))
    np.testing.assert_allclose(flipped.mesh.normals, np.tile([0, 0, -1], (3, 1)))
    assert flipped.mesh.faces.tolist() == [[0, 2, 1]]
