"""The compat suite's assets (meshes with uvs and normals, 8-bit and float textures, an
environment map), written by ``python tests/compat/make_refs.py --assets`` and committed:
the meshes' uvs are rotated against x, y so that a frame from dp/du differs from one built
from the normal alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def uv_sphere(nu: int = 24, nv: int = 12):
    """Positions, normals, uvs (rotated 30 degrees) and triangles of a unit uv sphere."""
    p, n, uv = [], [], []
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    for j in range(nv + 1):
        th = np.pi * j / nv
        for i in range(nu + 1):
            ph = 2 * np.pi * i / nu
            d = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
            p.append(d)
            n.append(d)
            u, v = i / nu, j / nv
            uv.append((c * u - s * v, s * u + c * v))
    tris = []
    for j in range(nv):
        for i in range(nu):
            a = j * (nu + 1) + i
            b, d, e = a + 1, a + nu + 1, a + nu + 2
            if j > 0:
                tris.append((a, d, b))
            if j < nv - 1:
                tris.append((b, d, e))
    return np.array(p), np.array(n), np.array(uv), np.array(tris)


def write_obj(path: Path) -> None:
    p, n, uv, tris = uv_sphere()
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in p]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in uv]
    lines += [f"vn {x:.6f} {y:.6f} {z:.6f}" for x, y, z in n]
    lines += ["f " + " ".join(f"{k + 1}/{k + 1}/{k + 1}" for k in t) for t in tris]
    path.write_text("\n".join(lines) + "\n")


def write_ply(path: Path) -> None:
    """The same sphere, squashed along z, as ASCII PLY with normals and u, v."""
    p, n, uv, tris = uv_sphere(20, 10)
    p = p * [1.0, 1.0, 0.7]
    n = n / [1.0, 1.0, 0.7]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    head = ["ply", "format ascii 1.0", f"element vertex {len(p)}",
            *(f"property float {k}" for k in ("x", "y", "z", "nx", "ny", "nz", "u", "v")),
            f"element face {len(tris)}", "property list uchar int vertex_indices", "end_header"]
    verts = [" ".join(f"{x:.6f}" for x in (*a, *b, *c)) for a, b, c in zip(p, n, uv)]
    faces = ["3 " + " ".join(str(int(k)) for k in t) for t in tris]
    path.write_text("\n".join(head + verts + faces) + "\n")


def write_images(folder: Path) -> None:
    from PIL import Image
    from rdsl.runtime.render.image import write_exr

    y, x = np.mgrid[0:16, 0:16]
    rgb = np.stack([(x * 16) % 256, ((x // 4 + y // 4) % 2) * 200 + 30, (y * 16) % 256], -1)
    Image.fromarray(rgb.astype(np.uint8), "RGB").save(folder / "tex_rgb.png")
    grey = (((x // 4 + y // 4) % 2) * 180 + 40).astype(np.uint8)
    Image.fromarray(grey, "L").save(folder / "tex_l.png")
    h = 0.5 + 0.5 * np.sin(x / 16 * 4 * np.pi) * np.cos(y / 16 * 2 * np.pi)
    Image.fromarray((h * 255).astype(np.uint8), "L").save(folder / "height.png")
    nx = 0.4 * np.cos(x / 16 * 4 * np.pi)
    ny = 0.3 * np.sin(y / 16 * 2 * np.pi)
    nn = np.stack([nx, ny, np.ones_like(nx)], -1)
    nn /= np.linalg.norm(nn, axis=-1, keepdims=True)
    Image.fromarray(((nn * 0.5 + 0.5) * 255).round().astype(np.uint8), "RGB").save(
        folder / "normal.png")
    ey, ex = np.mgrid[0:16, 0:32]
    env = np.stack([0.3 + 0.2 * (ex / 32), 0.3 + 0.0 * ey, 0.5 - 0.3 * (ey / 16)], -1)
    env[3:5, 8:11] = [40.0, 35.0, 30.0]
    write_exr(folder / "env.exr", env.astype(np.float32))
    write_exr(folder / "tex_float.exr", (rgb / 255.0 * 1.2).astype(np.float32))


def write_all(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_obj(folder / "sphere.obj")
    write_ply(folder / "sphere.ply")
    write_images(folder)
