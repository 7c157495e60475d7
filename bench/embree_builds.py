"""Embree builds on the same rays: the embreex wheel's Embree 4 (what rdsl links), Mitsuba 3's
own Embree 3 (its wheel's ``libembree3.so``, symbols in a ``mitsuba::`` namespace) and
Debian's ``libembree3-3``, each present one timed on identical packets of 16 rays.

    python bench/embree_builds.py [--spp 16] [--repeat 5]

The scenes are the material preview's two meshes (bench/scenes/set/gen: the 9k-triangle blob
and the 100k-triangle knot) on a ground quad; the rays are a 128x128 camera's (``--spp``
jittered rays per pixel, packets of consecutive pixels as rdsl's kernels trace them) and,
from their hits, rays in random upper-hemisphere directions (the first bounce).  A small C
program (compiled here with ``cc``) builds each library's scene at build quality high and
calls ``rtcIntersect16`` on every packet, one thread, best of ``--repeat``; it prints Mrays/s
per library.  A library that is not installed is skipped (``apt-get install libembree3-3``,
``pip install mitsuba``).  Not a test: docs/bench.md has the numbers.
"""

from __future__ import annotations

import argparse
import ctypes.util
import importlib.util
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench" / "scenes"))

# rtcNewDevice ... rtcIntersect16, and their names in Mitsuba's namespaced build
FUNCTIONS = {
    "rtcNewDevice": "_ZN7mitsuba12rtcNewDeviceEPKc",
    "rtcNewScene": "_ZN7mitsuba11rtcNewSceneEPNS_11RTCDeviceTyE",
    "rtcNewGeometry": "_ZN7mitsuba14rtcNewGeometryEPNS_11RTCDeviceTyENS_15RTCGeometryTypeE",
    "rtcSetNewGeometryBuffer": "_ZN7mitsuba23rtcSetNewGeometryBufferEPNS_13RTCGeometryTyENS_"
                               "13RTCBufferTypeEjNS_9RTCFormatEmm",
    "rtcCommitGeometry": "_ZN7mitsuba17rtcCommitGeometryEPNS_13RTCGeometryTyE",
    "rtcAttachGeometry": "_ZN7mitsuba17rtcAttachGeometryEPNS_10RTCSceneTyEPNS_13RTCGeometryTyE",
    "rtcSetSceneBuildQuality": "_ZN7mitsuba23rtcSetSceneBuildQualityEPNS_10RTCSceneTyENS_"
                               "15RTCBuildQualityE",
    "rtcSetGeometryBuildQuality": "_ZN7mitsuba26rtcSetGeometryBuildQualityEPNS_13RTCGeometryTy"
                                  "ENS_15RTCBuildQualityE",
    "rtcCommitScene": "_ZN7mitsuba14rtcCommitSceneEPNS_10RTCSceneTyE",
    "rtcIntersect16": "_ZN7mitsuba14rtcIntersect16EPKiPNS_10RTCSceneTyEPNS_19RTCIntersect"
                      "ContextEPNS_11RTCRayHit16E",
}

PROGRAM = r"""
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
typedef struct {
  float org_x[16], org_y[16], org_z[16], tnear[16], dir_x[16], dir_y[16], dir_z[16], time[16],
        tfar[16];
  unsigned mask[16], id[16], flags[16];
  float Ng_x[16], Ng_y[16], Ng_z[16], u[16], v[16];
  unsigned primID[16], geomID[16], instID[16], instPrimID[16];
} __attribute__((aligned(64))) RayHit16;
/* Embree 3's RTCIntersectContext: flags, filter, instID[1] (and room to spare) */
typedef struct { int flags; void *filter; unsigned instID[1]; float spare[4]; } Context3;
static double now(void) {
  struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + t.tv_nsec * 1e-9;
}
#define F(name) void *name = dlsym(lib, argv[k++])
int main(int argc, char **argv) {
  void *lib = dlopen(argv[1], RTLD_NOW);
  if (!lib) { printf("error %s\n", dlerror()); return 1; }
  int embree3 = atoi(argv[2]), repeat = atoi(argv[5]), k = 6;
  F(new_device); F(new_scene); F(new_geometry); F(set_buffer); F(commit_geometry);
  F(attach); F(scene_quality); F(geometry_quality); F(commit_scene); F(intersect16);
  FILE *f = fopen(argv[3], "rb"); unsigned nv, nt;
  if (fread(&nv, 4, 1, f) != 1 || fread(&nt, 4, 1, f) != 1) return 2;
  float *V = malloc(nv * 12); unsigned *T = malloc(nt * 12);
  if (fread(V, 12, nv, f) != nv || fread(T, 12, nt, f) != nt) return 2;
  fclose(f);
  void *dev = ((void *(*)(const char *))new_device)("");
  void *scene = ((void *(*)(void *))new_scene)(dev);
  void *g = ((void *(*)(void *, int))new_geometry)(dev, 0);             /* triangles */
  void *(*buffer)(void *, int, unsigned, int, size_t, size_t) = set_buffer;
  memcpy(buffer(g, 1, 0, 0x9003, 12, nv), V, nv * 12);                  /* vertex, float3 */
  memcpy(buffer(g, 0, 0, 0x5003, 12, nt), T, nt * 12);                  /* index, uint3 */
  ((void (*)(void *, int))geometry_quality)(g, 2);                      /* high */
  ((void (*)(void *))commit_geometry)(g);
  ((unsigned (*)(void *, void *))attach)(scene, g);
  ((void (*)(void *, int))scene_quality)(scene, 2);
  ((void (*)(void *))commit_scene)(scene);
  f = fopen(argv[4], "rb"); unsigned nr;
  if (fread(&nr, 4, 1, f) != 1) return 2;
  float *R = malloc((size_t)nr * 28);
  if (fread(R, 28, nr, f) != nr) return 2;
  fclose(f);
  RayHit16 rh; int valid[16]; Context3 ctx = {0, 0, {0xffffffffu}, {0}};
  double best = 1e30; long hits = 0;
  for (int rep = 0; rep < repeat; rep++) {
    double t0 = now(); hits = 0;
    for (unsigned p = 0; p + 16 <= nr; p += 16) {
      for (int i = 0; i < 16; i++) {
        float *r = R + 7 * (size_t)(p + i);
        rh.org_x[i] = r[0]; rh.org_y[i] = r[1]; rh.org_z[i] = r[2];
        rh.dir_x[i] = r[3]; rh.dir_y[i] = r[4]; rh.dir_z[i] = r[5]; rh.tfar[i] = r[6];
        rh.tnear[i] = 0; rh.time[i] = 0; rh.mask[i] = ~0u; rh.id[i] = 0; rh.flags[i] = 0;
        rh.geomID[i] = ~0u; rh.instID[i] = ~0u; valid[i] = -1;
      }
      if (embree3)
        ((void (*)(const int *, void *, void *, void *))intersect16)(valid, scene, &ctx, &rh);
      else
        ((void (*)(const int *, void *, void *, void *))intersect16)(valid, scene, &rh, NULL);
      for (int i = 0; i < 16; i++) hits += rh.geomID[i] != ~0u;
    }
    double dt = now() - t0;
    if (dt < best) best = dt;
  }
  printf("%u %ld %.6f\n", nr, hits, best);
  return 0;
}
"""


def libraries() -> list[tuple[str, Path, bool, bool]]:
    """(label, path, Embree 3's API, Mitsuba's namespaced symbols) of the builds present."""
    from rdsl.core.embree_abi import embree_library_path

    out = [("embreex Embree 4 (rdsl)", Path(embree_library_path()), False, False)]
    spec = importlib.util.find_spec("mitsuba")
    if spec is not None and spec.origin:
        lib = Path(spec.origin).parent / "libembree3.so"
        if lib.is_file():
            out.append(("Mitsuba 3's Embree 3", lib, True, True))
    found = ctypes.util.find_library("embree3")
    if found:
        for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib"):
            if (Path(d) / found).is_file():
                out.append(("Debian's Embree 3", Path(d) / found, True, False))
                break
    return out


def write_inputs(folder: Path, name: str, spp: int) -> dict[str, Path]:
    """The mesh and the two ray sets of one scene, as the C program reads them."""
    from rdsl.runtime.embree import EmbreeScene
    from rdsl.runtime.scene.meshes import load_ply

    import make_set

    make_set.generate()
    mesh = load_ply(ROOT / "bench" / "scenes" / "set" / "gen" / f"{name}.ply")
    v = np.asarray(mesh.vertices, np.float32)
    quad = np.array([[-4, -1, -4], [4, -1, -4], [4, -1, 4], [-4, -1, 4]], np.float32)
    n = len(v)
    verts = np.concatenate([v, quad])
    faces = np.concatenate([np.asarray(mesh.faces, np.uint32),
                            np.array([[n, n + 1, n + 2], [n, n + 2, n + 3]], np.uint32)])
    paths = {"mesh": folder / f"{name}.mesh"}
    with paths["mesh"].open("wb") as f:
        f.write(np.array([len(verts), len(faces)], np.uint32).tobytes())
        f.write(verts.tobytes())
        f.write(faces.tobytes())
    rng = np.random.default_rng(1)
    w = h = 128
    origin = np.array([0.0, 1.2, 4.2], np.float32)  # the material preview's camera
    fwd = np.array([0.0, -1.4, -4.2], np.float32)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    t = np.tan(np.radians(35 / 2))
    scene = EmbreeScene([(verts, faces)], quality="high")
    primary, secondary = [], []
    for _ in range(spp):
        px = (np.arange(w * h) % w + rng.random(w * h)) / w * 2 - 1
        py = 1 - (np.arange(w * h) // w + rng.random(w * h)) / h * 2
        d = fwd + t * px[:, None] * right + t * py[:, None] * up
        d = (d / np.linalg.norm(d, axis=1)[:, None]).astype(np.float32)
        o = np.broadcast_to(origin, d.shape).astype(np.float32)
        far = np.full((len(d), 1), np.inf, np.float32)
        primary.append(np.concatenate([o, d, far], 1))
        tt = scene.intersect(o, d)["t"]
        ok = np.isfinite(tt)
        p = o + d * np.where(ok, tt, 0)[:, None]
        r = rng.standard_normal((len(d), 3)).astype(np.float32)
        r /= np.linalg.norm(r, axis=1)[:, None]
        r[:, 1] = np.abs(r[:, 1])
        secondary.append(np.concatenate([p + 1e-3 * r, r, far], 1)[ok])
    scene.close()
    for kind, rays in (("primary", primary), ("secondary", secondary)):
        rays = np.concatenate(rays).astype(np.float32)
        paths[kind] = folder / f"{name}.{kind}.rays"
        with paths[kind].open("wb") as f:
            f.write(np.array([len(rays)], np.uint32).tobytes())
            f.write(rays.tobytes())
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    libs = libraries()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "bench.c").write_text(PROGRAM)
        exe = folder / "bench"
        subprocess.run(["cc", "-O2", "-o", str(exe), str(folder / "bench.c"), "-ldl"],
                       check=True)
        print(f"{'scene':6} {'rays':10} " + "  ".join(f"{label:>24}" for label, *_ in libs))
        for name in ("blob", "knot"):
            paths = write_inputs(folder, name, args.spp)
            for kind in ("primary", "secondary"):
                cells = []
                for _label, lib, embree3, namespaced in libs:
                    names = [FUNCTIONS[f] if namespaced else f for f in FUNCTIONS]
                    run = subprocess.run(
                        [str(exe), str(lib), str(int(embree3)), str(paths["mesh"]),
                         str(paths[kind]), str(args.repeat), *names],
                        capture_output=True, text=True, env={"LD_LIBRARY_PATH": str(lib.parent)})
                    got = run.stdout.split()
                    if run.returncode != 0 or len(got) != 3:
                        cells.append(f"{'failed':>24}")
                        continue
                    rays, _hits, seconds = int(got[0]), int(got[1]), float(got[2])
                    cells.append(f"{rays / seconds * 1e-6:>15.2f} Mrays/s")
                print(f"{name:6} {kind:10} " + "  ".join(cells), flush=True)
    print("one thread, packets of 16 (rtcIntersect16), build quality high; best of "
          f"{args.repeat} passes over the rays")


if __name__ == "__main__":
    main()
