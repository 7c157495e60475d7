"""Run by tests/test_instancing.py in a fresh process: load and render a scene of N
instances of a ~10k-triangle PLY mesh with Embree, and print (JSON) the peak RSS.

Also by hand: ``python tests/_instancing_rss.py FOLDER N`` (docs/plugins.md quotes it)."""

from __future__ import annotations

import json
import resource
import sys
from pathlib import Path

import numpy as np


def write_mesh(path: Path, n: int = 71) -> tuple[int, int]:
    """A latitude-longitude sphere of 2 n (n - 1) triangles (9940 for n = 71) as ASCII PLY:
    (triangles, bytes of its float32 vertices and uint32 triangles)."""
    th, ph = np.meshgrid(np.linspace(0, np.pi, n), np.linspace(0, 2 * np.pi, n),
                         indexing="ij")
    v = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)],
                 -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).reshape(-1)
    f = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    with open(path, "w") as fh:
        fh.write(f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\n"
                 f"property float y\nproperty float z\nelement face {len(f)}\n"
                 "property list uchar int vertex_indices\nend_header\n")
        np.savetxt(fh, v, fmt="%.6f")
        np.savetxt(fh, np.hstack([np.full((len(f), 1), 3), f]), fmt="%d")
    return len(f), 12 * len(v) + 12 * len(f)


def write_scene(path: Path, count: int) -> None:
    """``count`` instances of mesh.ply on a square grid seen by an 8x8 camera."""
    k = int(np.ceil(np.sqrt(count)))
    inst = "".join(
        f'<shape type="instance"><ref id="g"/><transform name="to_world"><scale '
        f'value="{1.5 / k:.5f}"/><translate x="{(i % k) / k * 4 - 2:.4f}" '
        f'y="{(i // k) / k * 4 - 2:.4f}"/></transform></shape>\n' for i in range(count))
    path.write_text(
        '<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="60"/>'
        '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>'
        '</transform><film type="hdrfilm"><integer name="width" value="8"/>'
        '<integer name="height" value="8"/></film></sensor>\n'
        '<shape type="shapegroup" id="g"><shape type="ply"><string name="filename" '
        f'value="mesh.ply"/></shape></shape>\n{inst}<emitter type="constant"/></scene>\n')


def main() -> None:
    import rdsl

    folder, count = Path(sys.argv[1]), int(sys.argv[2])
    triangles, mesh_bytes = write_mesh(folder / "mesh.ply")
    path = folder / f"instances{count}.xml"
    write_scene(path, count)
    img = rdsl.load_scene(path, accel="embree").render(spp=1)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"instances": count, "triangles": triangles, "mesh_bytes": mesh_bytes,
                      "maxrss_kib": rss, "mean": float(np.mean(img))}))


if __name__ == "__main__":
    main()
