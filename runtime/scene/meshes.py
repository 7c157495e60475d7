"""Triangle meshes: OBJ, PLY and Mitsuba ``.serialized`` loaders and the analytic shapes.

Every loader returns a :class:`Mesh` in object space; :func:`to_world` moves it to world
space and applies ``flip_normals`` / ``face_normals``.  Triangles wind counter-clockwise
around their geometric normal, so ``cross(v1 - v0, v2 - v0)`` points outwards.  A file that
cannot be read raises :class:`MeshError` with a message; the scene loader adds the file name
and the XML line.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...compiler.ir import F32_OVERFLOW
from . import transform as xf
from .mesh_attributes import ply_attributes


class MeshError(ValueError):
    """A mesh file is malformed or unsupported."""


@dataclass
class Mesh:
    """An indexed triangle mesh.  ``normals`` is ``None`` when face normals are used."""

    vertices: np.ndarray            # (N, 3) float32
    faces: np.ndarray               # (M, 3) uint32
    normals: np.ndarray | None = None  # (N, 3) float32
    uvs: np.ndarray | None = None      # (N, 2) float32
    face_normals: bool = False
    # PLY attributes by Mitsuba's name (vertex_color, face_id...): (N or M, 1 or 3) float32
    attributes: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.uint32).reshape(-1, 3)
        if self.normals is not None:
            self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
        if self.uvs is not None:
            self.uvs = np.ascontiguousarray(self.uvs, dtype=np.float32).reshape(-1, 2)

    def validate(self) -> Mesh:
        n = len(self.vertices)
        if len(self.faces) == 0:
            raise MeshError("the mesh has no triangles")
        if self.faces.max() >= n:
            raise MeshError(f"a face refers to vertex {int(self.faces.max())}, but the mesh "
                            f"has only {n} vertices")
        for name, arr in (("normals", self.normals), ("uvs", self.uvs)):
            if arr is not None and len(arr) != n:
                raise MeshError(f"{len(arr)} {name} for {n} vertices")
        for name, arr in self.attributes.items():
            count = n if name.startswith("vertex_") else len(self.faces)
            if len(arr) != count or not np.all(np.isfinite(arr)):
                raise MeshError(f"attribute '{name}' has {len(arr)} finite values for {count} "
                                f"{'vertices' if count == n else 'triangles'}")
        if not np.all(np.isfinite(self.vertices)):
            raise MeshError("vertex positions contain NaN or infinity")
        return self


def vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Angle-weighted vertex normals, as Mitsuba's ``recompute_vertex_normals``."""
    v = v.astype(np.float64)
    f = f.astype(np.int64)
    p = v[f]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    ln = np.linalg.norm(fn, axis=1, keepdims=True)
    fn = fn / np.where(ln > 0, ln, 1.0)
    acc = np.zeros_like(v)
    for k in range(3):
        e1 = p[:, (k + 1) % 3] - p[:, k]
        e2 = p[:, (k + 2) % 3] - p[:, k]
        n1 = np.linalg.norm(e1, axis=1)
        n2 = np.linalg.norm(e2, axis=1)
        cosang = np.einsum("ij,ij->i", e1, e2) / np.maximum(n1 * n2, 1e-300)
        ang = np.arccos(np.clip(cosang, -1.0, 1.0))
        np.add.at(acc, f[:, k], fn * ang[:, None])
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    out = acc / np.where(ln > 0, ln, 1.0)
    out[ln[:, 0] == 0] = (0.0, 0.0, 1.0)
    return out


def to_world(mesh: Mesh, m: np.ndarray, flip_normals: bool = False,
             face_normals: bool = False) -> Mesh:
    """Transform to world space; flip the winding and normals; drop normals for faceting."""
    v = xf.apply_points(m, mesh.vertices)
    if not np.all(np.abs(v) < F32_OVERFLOW):  # NaN fails this too
        raise MeshError("its vertices in world space are not finite 32-bit floats (check "
                        "'to_world' and the shape's size)")
    f = mesh.faces
    if np.linalg.det(m[:3, :3]) < 0:
        f = f[:, [0, 2, 1]]  # a mirroring transform would turn the surface inside out
    if face_normals:
        n = None
    elif mesh.normals is not None:
        n = xf.apply_normals(m, mesh.normals)
    else:
        n = vertex_normals(v, f)
    if flip_normals:
        f = f[:, [0, 2, 1]]
        n = None if n is None else -n
    return replace(mesh, vertices=v, faces=f, normals=n, face_normals=face_normals)


# ---------------------------------------------------------------------------------------
# Analytic shapes (object space)

def rectangle() -> Mesh:
    """Mitsuba's ``rectangle``: [-1, 1]^2 at z = 0, normal +z."""
    v = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
    return Mesh(np.array(v), np.array([(0, 1, 2), (2, 3, 0)]), np.tile([0, 0, 1], (4, 1)),
                np.array(uv))


def cube() -> Mesh:
    """Mitsuba's ``cube``: [-1, 1]^3, 24 vertices and 12 triangles with outward normals, in
    Mitsuba 3's order, with its uvs (a texture lands on each face as in Mitsuba's)."""
    # per face: its normal's axis and sign, then its four corners as Mitsuba's table lists
    # them, with uvs (0, 1) (1, 1) (1, 0) (0, 0) and triangles (0 1 2) (3 0 2)
    table = ((1, -1.0, ((1, -1, -1), (1, -1, 1), (-1, -1, 1), (-1, -1, -1))),
             (1, 1.0, ((1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1))),
             (0, 1.0, ((1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1))),
             (2, 1.0, ((1, -1, 1), (1, 1, 1), (-1, 1, 1), (-1, -1, 1))),
             (0, -1.0, ((-1, -1, 1), (-1, 1, 1), (-1, 1, -1), (-1, -1, -1))),
             (2, -1.0, ((1, 1, -1), (1, -1, -1), (-1, -1, -1), (-1, 1, -1))))
    verts, norms, faces = [], [], []
    for axis, sign, corners in table:
        n = np.zeros(3)
        n[axis] = sign
        base = len(verts)
        verts += corners
        norms += [n] * 4
        faces += [(base, base + 1, base + 2), (base + 3, base, base + 2)]
    uvs = [(0, 1), (1, 1), (1, 0), (0, 0)] * 6
    return Mesh(np.array(verts, np.float64), np.array(faces), np.array(norms), np.array(uvs,
                                                                                      np.float64))


def disk(segments: int = 96) -> Mesh:
    """Mitsuba's ``disk``: the unit disk at z = 0, normal +z, uv = (r, phi / 2pi)."""
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    ring = np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=1)
    v = np.vstack([[0.0, 0.0, 0.0], ring])
    uv = np.vstack([[0.0, 0.0], np.stack([np.ones_like(phi), phi / (2 * np.pi)], axis=1)])
    i = np.arange(1, segments + 1)
    f = np.stack([np.zeros_like(i), i, i + 1], axis=1)
    return Mesh(v, f, np.tile([0.0, 0.0, 1.0], (len(v), 1)), uv)


def sphere(rings: int = 48, segments: int = 96) -> Mesh:
    """A UV sphere of radius 1 at the origin; uv = (phi / 2pi, theta / pi) as Mitsuba."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    p = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    uv = np.stack([ph / (2 * np.pi), th / np.pi], axis=-1)
    w = segments + 1
    i, j = np.meshgrid(np.arange(rings), np.arange(segments), indexing="ij")
    a = (i * w + j).ravel()
    b, c = a + 1, a + w
    d = c + 1
    row = i.ravel()
    t1 = np.stack([a, c, d], axis=1)[row < rings - 1]   # the last row's c, d are the pole
    t2 = np.stack([a, d, b], axis=1)[row > 0]           # the first row's a, b are the pole
    v = p.reshape(-1, 3)
    return Mesh(v, np.vstack([t1, t2]), v.copy(), uv.reshape(-1, 2))


# ---------------------------------------------------------------------------------------
# Wavefront OBJ

def _obj_index(tok: str, count: int, what: str, lineno: int) -> int:
    try:
        i = int(tok)
    except ValueError:
        raise MeshError(f"line {lineno}: bad {what} index {tok!r}") from None
    if i == 0:
        raise MeshError(f"line {lineno}: {what} index 0 (OBJ indices start at 1)")
    j = i - 1 if i > 0 else count + i
    if not 0 <= j < count:
        raise MeshError(f"line {lineno}: {what} index {i} out of range (have {count})")
    return j


def load_obj(path: Path, flip_tex_coords: bool = True) -> Mesh:
    """Read positions, texture coordinates and normals; polygons become triangle fans."""
    pos: list[list[float]] = []
    tex: list[list[float]] = []
    nrm: list[list[float]] = []
    keys: dict[tuple[int, int, int], int] = {}
    corners: list[tuple[int, int, int]] = []
    faces: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split()
            if not parts:
                continue
            tag = parts[0]
            try:
                if tag == "v":
                    pos.append([float(x) for x in parts[1:4]])
                    if len(pos[-1]) != 3:
                        raise ValueError
                elif tag == "vt":
                    uv = [float(x) for x in parts[1:3]] + [0.0]
                    tex.append(uv[:2])
                elif tag == "vn":
                    nrm.append([float(x) for x in parts[1:4]])
                    if len(nrm[-1]) != 3:
                        raise ValueError
            except ValueError:
                raise MeshError(f"line {lineno}: cannot parse {line.strip()!r}") from None
            if tag != "f":
                continue
            if len(parts) < 4:
                raise MeshError(f"line {lineno}: a face needs at least 3 vertices")
            ids = []
            for tok in parts[1:]:
                sub = tok.split("/")
                vi = _obj_index(sub[0], len(pos), "vertex", lineno)
                ti = (_obj_index(sub[1], len(tex), "texture", lineno)
                      if len(sub) > 1 and sub[1] else -1)
                ni = (_obj_index(sub[2], len(nrm), "normal", lineno)
                      if len(sub) > 2 and sub[2] else -1)
                key = (vi, ti, ni)
                k = keys.get(key)
                if k is None:
                    k = keys[key] = len(corners)
                    corners.append(key)
                ids.append(k)
            faces += [(ids[0], ids[i], ids[i + 1]) for i in range(1, len(ids) - 1)]
    if not faces:
        raise MeshError("no faces ('f' lines) found")
    c = np.array(corners, dtype=np.int64)
    v = np.asarray(pos, dtype=np.float64)[c[:, 0]]
    uvs = None
    if (c[:, 1] >= 0).any():
        uvs = np.zeros((len(c), 2))
        has = c[:, 1] >= 0
        uvs[has] = np.asarray(tex)[c[has, 1]]
        if flip_tex_coords:
            uvs[:, 1] = 1.0 - uvs[:, 1]
    normals = np.asarray(nrm)[c[:, 2]] if (c[:, 2] >= 0).all() else None
    return Mesh(v, np.array(faces), normals, uvs).validate()


# ---------------------------------------------------------------------------------------
# Stanford PLY

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


@dataclass
class _PlyElement:
    name: str
    count: int
    props: list[tuple[str, str, str | None]]  # (name, type, list item type or None)


def _ply_type(t: str) -> str:
    if t not in _PLY_TYPES:
        raise MeshError(f"unknown PLY property type '{t}'")
    return _PLY_TYPES[t]


def _ply_header(data: bytes) -> tuple[str, list[_PlyElement], int]:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshError("not a PLY file (missing 'ply' magic or 'end_header')")
    body = data.index(b"\n", end) + 1
    fmt = None
    elements: list[_PlyElement] = []
    for line in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        w = line.split()
        if not w or w[0] in ("comment", "obj_info"):
            continue
        if w[0] == "format":
            fmt = w[1]
        elif w[0] == "element":
            elements.append(_PlyElement(w[1], int(w[2]), []))
        elif w[0] == "property" and elements:
            if w[1] == "list":
                elements[-1].props.append((w[4], _ply_type(w[2]), _ply_type(w[3])))
            else:
                elements[-1].props.append((w[2], _ply_type(w[1]), None))
        else:
            raise MeshError(f"unexpected PLY header line {line!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshError(f"unsupported PLY format {fmt!r}; accepted: ascii, "
                        "binary_little_endian, binary_big_endian")
    return fmt, elements, body


def _fixed_dtype(el: _PlyElement, order: str, list_len: int) -> np.dtype:
    fields = []
    for name, t, item in el.props:
        if item is None:
            fields.append((name, order + t))
        else:
            fields.append((name + "#n", order + t))
            fields.append((name, order + item, (list_len,)))
    return np.dtype(fields)


def _read_binary(el: _PlyElement, data: bytes, off: int, order: str) -> tuple[dict, int]:
    lists = [p for p in el.props if p[2] is not None]
    if not lists:
        dt = _fixed_dtype(el, order, 0)
        arr = np.frombuffer(data, dt, el.count, off)
        return {n: arr[n] for n, _, _ in el.props}, off + dt.itemsize * el.count
    # Fast path: every row's lists have the length of the first row's (all triangles).
    first = {}
    o = off
    for name, t, item in el.props:
        dt = np.dtype(order + t)
        val = np.frombuffer(data, dt, 1, o)[0]
        o += dt.itemsize
        if item is not None:
            first[name] = int(val)
            o += int(val) * np.dtype(item).itemsize
    k = max(first.values()) if first else 0
    if len(set(first.values())) == 1:
        dt = _fixed_dtype(el, order, k)
        if off + dt.itemsize * el.count <= len(data):
            arr = np.frombuffer(data, dt, el.count, off)
            if all((arr[n + "#n"] == k).all() for n in first):
                return {n: arr[n] for n, _, _ in el.props}, off + dt.itemsize * el.count
    out: dict[str, list] = {n: [] for n, _, _ in el.props}
    for _ in range(el.count):
        for name, t, item in el.props:
            dt = np.dtype(order + t)
            val = np.frombuffer(data, dt, 1, off)[0]
            off += dt.itemsize
            if item is not None:
                idt = np.dtype(order + item)
                out[name].append(np.frombuffer(data, idt, int(val), off))
                off += int(val) * idt.itemsize
            else:
                out[name].append(val)
    return out, off


def _read_ascii(el: _PlyElement, tok: list[str], pos: int) -> tuple[dict, int]:
    out: dict[str, list] = {n: [] for n, _, _ in el.props}
    for _ in range(el.count):
        for name, t, item in el.props:
            if item is None:
                out[name].append(float(tok[pos]))
                pos += 1
            else:
                n = int(tok[pos])
                out[name].append([float(x) for x in tok[pos + 1:pos + 1 + n]])
                pos += 1 + n
    return out, pos


def load_ply(path: Path, flip_tex_coords: bool = False) -> Mesh:
    """ASCII or binary PLY with ``vertex`` (x y z, nx ny nz, u v / s t) and ``face``."""
    data = Path(path).read_bytes()
    fmt, elements, off = _ply_header(data)
    values: dict[str, dict] = {}
    try:
        if fmt == "ascii":
            tok = data[off:].decode("ascii", errors="replace").split()
            pos = 0
            for el in elements:
                values[el.name], pos = _read_ascii(el, tok, pos)
        else:
            order = "<" if fmt == "binary_little_endian" else ">"
            for el in elements:
                values[el.name], off = _read_binary(el, data, off, order)
    except (IndexError, ValueError) as e:
        raise MeshError(f"truncated or malformed PLY data ({e})") from None
    vert, face = values.get("vertex"), values.get("face")
    if vert is None or face is None:
        raise MeshError("a PLY mesh needs 'vertex' and 'face' elements")
    if not all(k in vert for k in "xyz"):
        raise MeshError("the PLY 'vertex' element lacks x, y or z")
    v = np.stack([np.asarray(vert[k], dtype=np.float64) for k in "xyz"], axis=1)
    n = (np.stack([np.asarray(vert[k], dtype=np.float64) for k in ("nx", "ny", "nz")], axis=1)
         if all(k in vert for k in ("nx", "ny", "nz")) else None)
    uv = None
    for a, b in _UV_NAMES:
        if a in vert and b in vert:
            uv = np.stack([np.asarray(vert[a], dtype=np.float64),
                           np.asarray(vert[b], dtype=np.float64)], axis=1)
            if flip_tex_coords:
                uv[:, 1] = 1.0 - uv[:, 1]
            break
    key = next((k for k in ("vertex_indices", "vertex_index") if k in face), None)
    if key is None:
        raise MeshError("the PLY 'face' element lacks 'vertex_indices' (or 'vertex_index')")
    polys = face[key]
    of_face = None  # the PLY face of each triangle, where polygons were split
    if isinstance(polys, np.ndarray) and polys.ndim == 2 and polys.shape[1] == 3:
        f = polys.astype(np.int64)
    else:
        tris, of_face = [], []
        for k, p in enumerate(polys):
            p = [int(x) for x in p]
            if len(p) < 3:
                raise MeshError(f"a PLY face has {len(p)} vertices")
            tris += [(p[0], p[i], p[i + 1]) for i in range(1, len(p) - 1)]
            of_face += [k] * (len(p) - 2)
        f = np.array(tris, dtype=np.int64).reshape(-1, 3)
    if len(f) and f.min() < 0:
        raise MeshError("a PLY face has a negative vertex index")
    props = {el.name: el.props for el in elements}
    attrs = ply_attributes("vertex", props["vertex"], vert, str(path))
    for name, a in ply_attributes("face", props["face"], face, str(path)).items():
        attrs[name] = a if of_face is None else a[np.asarray(of_face, np.int64)]
    return Mesh(v, f, n, uv, attributes=attrs).validate()


# ---------------------------------------------------------------------------------------
# Mitsuba .serialized

SERIALIZED_MAGIC = 0x041C
SER_NORMALS, SER_UVS, SER_COLORS, SER_FACE_NORMALS = 0x0001, 0x0002, 0x0008, 0x0010
SER_SINGLE, SER_DOUBLE = 0x1000, 0x2000


def load_serialized(path: Path, shape_index: int = 0) -> Mesh:
    """Mesh ``shape_index`` of a Mitsuba ``.serialized`` file (format versions 3 and 4)."""
    data = Path(path).read_bytes()
    if len(data) < 8:
        raise MeshError("file too short to be a .serialized mesh")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != SERIALIZED_MAGIC:
        raise MeshError(f"invalid file format identifier 0x{magic:04X} (expected 0x041C)")
    if version not in (3, 4):
        raise MeshError(f"unsupported .serialized version {version} (accepted: 3, 4)")
    if shape_index < 0:
        raise MeshError("shape_index must be non-negative")
    offset = 0
    if shape_index > 0:
        (count,) = struct.unpack_from("<I", data, len(data) - 4)
        if shape_index >= count:
            raise MeshError(f"shape_index {shape_index} is out of range: the file holds "
                            f"{count} mesh(es)")
        if version == 4:
            (offset,) = struct.unpack_from("<Q", data, len(data) - 8 * (count - shape_index) - 4)
        else:
            (offset,) = struct.unpack_from("<I", data, len(data) - 4 * (count - shape_index + 1))
        if offset + 4 > len(data):
            raise MeshError(f"corrupt end-of-file dictionary (offset {offset})")
        magic, version = struct.unpack_from("<HH", data, offset)
        if magic != SERIALIZED_MAGIC:
            raise MeshError(f"mesh {shape_index} does not start with the 0x041C header")
    try:
        raw = zlib.decompressobj().decompress(data[offset + 4:])
    except zlib.error as e:
        raise MeshError(f"corrupt zlib stream ({e})") from None
    return _parse_serialized(raw, version)


def _parse_serialized(raw: bytes, version: int) -> Mesh:
    try:
        (flags,) = struct.unpack_from("<I", raw, 0)
        pos = 4
        if version == 4:
            end = raw.index(b"\0", pos)
            pos = end + 1
        nv, nf = struct.unpack_from("<QQ", raw, pos)
        pos += 16
        ftype = np.dtype("<f8") if flags & SER_DOUBLE else np.dtype("<f4")

        def take(dtype: np.dtype, n: int) -> np.ndarray:
            nonlocal pos
            if pos + dtype.itemsize * n > len(raw):
                raise MeshError("truncated mesh data")
            arr = np.frombuffer(raw, dtype, n, pos)
            pos += dtype.itemsize * n
            return arr

        v = take(ftype, 3 * nv).reshape(-1, 3)
        n = take(ftype, 3 * nv).reshape(-1, 3) if flags & SER_NORMALS else None
        uv = take(ftype, 2 * nv).reshape(-1, 2) if flags & SER_UVS else None
        if flags & SER_COLORS:
            take(ftype, 3 * nv)
        itype = np.dtype("<u8") if nv > 0xFFFFFFFF else np.dtype("<u4")
        f = take(itype, 3 * nf).reshape(-1, 3)
    except (struct.error, ValueError) as e:
        if isinstance(e, MeshError):
            raise
        raise MeshError(f"truncated mesh data ({e})") from None
    return Mesh(v, f, n, uv, face_normals=bool(flags & SER_FACE_NORMALS)).validate()


def read_mesh(kind: str, path: Path, params: dict) -> Mesh:
    """A mesh file of shape type ``kind`` (obj, ply, serialized) parsed with the shape's
    ``params`` (``to_world`` not applied: the result is shared by reloads)."""
    if kind == "obj":
        return load_obj(path, params["flip_tex_coords"])
    if kind == "ply":
        return load_ply(path, params["flip_tex_coords"])
    return load_serialized(path, params["shape_index"])
