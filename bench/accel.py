"""Embree against the BVH written in rdsl (``--accel bvh``): render time of a few scenes
with each, their ratio, and the build times of both acceleration structures.  Not a test:
run it by hand.

    python bench/accel.py [--spp 16] [--repeat 3] [--res 128] [--leaf-size 4]

Also the closest-hit rate of each on a million random rays, one thread.  Scenes: the
Cornell box, a scene of an OBJ mesh, spheres and disks (tests/test_bvh.py's),
and a generated height-field mesh of about 100k triangles.  The two renders of a scene
alternate (``--repeat`` times) and each time is the median, so the machine's load affects
both alike; kernels are compiled (or loaded from the cache) before timing.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rdsl
from rdsl.runtime.embree import EmbreeScene
from rdsl.runtime.render.bvh import scene_bvh

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from _scenes import CBOX  # noqa: E402
from test_bvh import SCENE as MIXED  # noqa: E402

BIG = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, -2.6, 1.6" target="0, 0, 0" up="0, 0, 1"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="$res"/>
      <integer name="height" value="$res"/></film>
  </sensor>
  <shape type="obj"><string name="filename" value="terrain.obj"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.45, 0.4"/></bsdf></shape>
  <shape type="sphere"><point name="center" x="-1" y="1" z="2.5"/><float name="radius" value="0.4"/>
    <emitter type="area"><rgb name="radiance" value="30, 30, 30"/></emitter></shape>
  <emitter type="constant"><rgb name="radiance" value="0.1, 0.1, 0.12"/></emitter>
</scene>
"""


def terrain(path: Path, n: int) -> int:
    """An n x n vertex height field over [-1, 1]^2 as OBJ: 2 (n - 1)^2 triangles."""
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))
    z = 0.15 * np.sin(7 * x) * np.cos(5 * y) + 0.05 * np.sin(31 * x + 17 * y)
    v = np.c_[x.ravel(), y.ravel(), z.ravel()]
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    f = np.r_[np.c_[i, i + 1, i + n + 1], np.c_[i, i + n + 1, i + n]] + 1
    with path.open("w") as out:
        np.savetxt(out, v, "v %.6f %.6f %.6f")
        np.savetxt(out, f, "f %d %d %d")
    return len(f)


def scenes(folder: Path, res: int) -> dict[str, tuple[Path, dict]]:
    shutil.copy(ROOT / "bench" / "scenes" / "compat" / "grid.obj", folder)
    (folder / "mixed.xml").write_text(MIXED.replace('value="40"', f'value="{res}"')
                                      .replace('value="32"', f'value="{res}"'))
    ntri = terrain(folder / "terrain.obj", 230)
    (folder / "terrain.xml").write_text(BIG.replace("$res", str(res)))
    return {"cbox": (CBOX, {"res": res}), "mixed": (folder / "mixed.xml", {}),
            f"terrain {ntri // 1000}k tris": (folder / "terrain.xml", {})}


RAY_SRC = {
    "bvh": """import render.bvh;
fn q(o: Vec3, d: Vec3, BV: [Float], BI: [Int], P: [Float], G: [Int]) -> Float {
    return bvh_trace(Ray { o: o, d: d, tmax: infinity() }, BV, BI, P, G).t;
}""",
    "embree": """fn q(o: Vec3, d: Vec3) -> Float {
    return trace(Ray { o: o, d: d, tmax: infinity() }).t;
}"""}


def ray_rates(bufs, n: int, repeat: int) -> tuple[float, float]:
    """Closest hits per second (millions, one thread) of Embree and of the BVH, for ``n``
    random rays from points in the scene's box (incoherent, as after a diffuse bounce)."""
    bvh, emb = rdsl.jit(RAY_SRC["bvh"]).q, rdsl.jit(RAY_SRC["embree"])
    scene = EmbreeScene(bufs.meshes, quality="low", mesh_quality="high")
    emb.bind_scene(scene)
    rng = np.random.default_rng(0)
    p = bufs.P[:3 * (len(bufs.P) // 3)].reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    o = (lo + (hi - lo) * (0.05 + 0.9 * rng.random((n, 3)))).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    runs = {"embree": lambda: emb.q(o, d, threads=1),
            "bvh": lambda: bvh(o, d, bufs.BV, bufs.BI, bufs.P, bufs.G, threads=1)}
    times: dict[str, list[float]] = {"embree": [], "bvh": []}
    for _ in range(repeat):
        for name, run in runs.items():
            t0 = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - t0)
    scene.close()
    return tuple(n / statistics.median(times[k]) / 1e6 for k in ("embree", "bvh"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--leaf-size", type=int, default=4)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, (path, defines) in scenes(Path(tmp), args.res).items():
            loaded = {a: rdsl.load_scene(path, accel=a, **defines) for a in ("embree", "bvh")}
            for scene in loaded.values():
                scene.compile()
                scene.render(spp=1, seed=0)  # warm up: threads, pages
            bufs = loaded["bvh"].buffers
            t0 = time.perf_counter()
            EmbreeScene(bufs.meshes, quality="low", mesh_quality="high").close()
            embree_build = time.perf_counter() - t0
            cpu = time.process_time()
            bufs.BV, bufs.BI, bvh = scene_bvh(bufs, leaf_size=args.leaf_size)  # renders use it
            cpu = time.process_time() - cpu  # on a loaded machine, what the build costs
            times: dict[str, list[float]] = {"embree": [], "bvh": []}
            for _ in range(args.repeat):
                for accel, scene in loaded.items():
                    t0 = time.perf_counter()
                    scene.render(spp=args.spp, seed=0)
                    times[accel].append(time.perf_counter() - t0)
            e, b = (statistics.median(times[a]) for a in ("embree", "bvh"))
            rays = ray_rates(bufs, 1 << 20, args.repeat)
            rows.append((name, len(bvh.prims), e, b, b / e, *rays, embree_build,
                         bvh.build_seconds, cpu, bvh.nodes))
    print(f"{args.res}x{args.res}, {args.spp} spp, median of {args.repeat} alternated renders; "
          f"BVH leaf size {args.leaf_size}; Mrays/s: closest hits of 1M random rays from "
          "inside the scene's box, one thread")
    head = ("scene", "prims", "embree s", "bvh s", "bvh/embree", "embree Mrays/s",
            "bvh Mrays/s", "embree build s", "bvh build s", "bvh build cpu s", "bvh nodes")
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for name, prims, e, b, r, re, rb, eb, bb, cpu, nodes in rows:
        print(f"| {name} | {prims} | {e:.3f} | {b:.3f} | {r:.2f}x | {re:.2f} | {rb:.2f} | "
              f"{eb:.3f} | {bb:.3f} | {cpu:.3f} | {nodes} |")


if __name__ == "__main__":
    main()
