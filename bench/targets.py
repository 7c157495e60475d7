"""Every target on two scenes (issue 14, item 7): the Cornell box and a height-field mesh of
100k+ triangles, rendered by avx512 with Embree, avx512 with the BVH written in rdsl, SIMD C
(``cc -O3 -march=native``, the host's widest width), OpenCL C on PoCL and SPIR-V on
lavapipe, all with the rdsl BVH but the first; PTX is compiled (and checked by ``ptxas``
where one is found) but not run without a CUDA GPU; Mitsuba 3 (``llvm_ad_rgb``) renders
the same scenes for comparison.  Per build: paths/s, rays/s and the equal-error time.  Not
a test: run it by hand (a few minutes; kernels are cached).

    python bench/targets.py [--seconds 1] [--repeat 3] [--mesh-res 128] [--ref-spp 1024]
                            [--no-mitsuba]

How it measures:

- Each build renders at the spp that takes about ``--seconds`` (a power of two, from a
  timed 1-spp render after the warm-up), ``--repeat`` times, the builds taking turns run
  by run (a shared machine's changing load hits them alike); times are medians of wall
  seconds with every core, seeds differ run by run.  paths/s = pixels x spp / seconds.
- rays/s = paths/s x the scene's rays per path, counted once: the avx512+Embree render at 4
  spp, one thread, under ``bench/ray_stats.c`` (an LD_PRELOAD shim counting the active lanes
  of rtcIntersect16 and rtcOccluded16: the path rays and the shadow rays).  Every build runs
  the same integrator and sampler from the same seeds, so it traces the same rays (to float
  rounding).
- RMSE against a reference: the Cornell box's ``examples/cbox/cbox_ref_rgb.exr`` (256x256,
  the scene's own resolution); the mesh scene's rendered once by avx512+Embree at
  ``--ref-spp`` (cached under ``out/targets/``).  The equal-error time is the time to reach
  the scene's fixed RMSE (the first build's at its spp, printed above the table), assuming
  RMSE falls as 1/sqrt(time): seconds x (RMSE / fixed RMSE)^2, with each build's median RMSE
  over its runs.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import rdsl
from rdsl.compiler.targets import get_target, host_supports, host_target
from rdsl.runtime.render.bench import mitsuba_variant, rmse
from rdsl.runtime.render.image import read_exr

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "out" / "targets"
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
sys.path.insert(0, str(ROOT / "bench"))
from accel import BIG, terrain

MESH_N = 230  # vertices per side of the height field: 2 * 229^2 = 104,882 triangles


def builds(only: str = "") -> list[tuple[str, str, int | None, str, dict[str, str]]]:
    """(label, target, width, accel, environment) of every build, the reference first;
    ``only``: comma-separated targets (``avx512,opencl``...) to keep besides the first."""
    llvm = "avx512" if host_supports(get_target("avx512")) else host_target().name
    w = get_target(llvm).width
    out = [(f"{llvm}+Embree", llvm, None, "embree", {}),
           (f"{llvm}+bvh", llvm, None, "bvh", {}),
           (f"c{w} -O3", "c", w, "bvh", {"RDSL_CFLAGS": "-O3"}),
           (f"opencl{w} (PoCL)", "opencl", w, "bvh", {}),
           ("spirv (lavapipe)", "spirv", None, "bvh", {})]
    keep = set(filter(None, only.split(",")))
    return [b for k, b in enumerate(out) if not keep or k == 0 or b[1] in keep]


def mesh_scene(res: int) -> Path:
    """The height field under a sphere light (bench/accel.py's), written under out/."""
    folder = OUT / "mesh"
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / "terrain.obj").is_file():
        terrain(folder / "terrain.obj", MESH_N)
    path = folder / f"terrain_{res}.xml"
    path.write_text(BIG.replace("$res", str(res)))
    return path


def reference(path: Path, spp: int, label_target: tuple[str, str]) -> np.ndarray:
    """``path`` rendered at ``spp`` by the first build, cached by the scene's texts."""
    h = hashlib.sha256(path.read_bytes())
    h.update((path.parent / "terrain.obj").read_bytes())
    file = OUT / f"ref_{h.hexdigest()[:16]}_{spp}.npy"
    if file.is_file():
        return np.load(file)
    t = time.perf_counter()
    target, accel = label_target
    img = rdsl.load_scene(path, target=target, accel=accel).render(spp=spp, seed=1 << 20)
    np.save(file, img[..., :3])
    print(f"  reference: {spp} spp in {time.perf_counter() - t:.1f} s", flush=True)
    return img[..., :3]


def rays_per_path(path: Path, defines: dict[str, int], target: str, pixels: int) -> float:
    """Rays (closest-hit and shadow) per path, counted by bench/ray_stats.c; NaN where the
    shim cannot count (no 16-wide Embree queries, or no C compiler)."""
    cc = shutil.which("cc")
    if cc is None or get_target(target).width != 16:
        return math.nan
    spp = 4
    with tempfile.TemporaryDirectory() as tmp:
        shim = Path(tmp) / "ray_stats.so"
        subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(shim),
                        str(ROOT / "bench" / "ray_stats.c"), "-ldl"], check=True)
        code = (f"import rdsl; rdsl.load_scene({str(path)!r}, target={target!r}, "
                f"**{defines!r}).render(spp={spp}, seed=0, threads=1)")
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           env=dict(os.environ, LD_PRELOAD=str(shim)), check=True)
    rays = sum(int(n) for n in re.findall(r"calls, (\d+) rays", r.stderr))
    return rays / (pixels * spp) if rays else math.nan


def load(path: Path, defines: dict[str, int], target: str, width: int | None, accel: str,
         env: dict[str, str]):
    """The scene loaded and compiled for one build (``env``: set while it compiles)."""
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        t = get_target(target, width)
        scene = rdsl.load_scene(path, target=t, accel=accel, **defines)
        scene.compile()
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return scene


def renderers(path: Path, defines: dict[str, int], mitsuba: bool,
              only: str = "") -> list[tuple[str, Any]]:
    """(label, render(spp, seed) -> RGB image) of every build, compiled; Mitsuba 3's
    ``llvm_ad_rgb`` (else ``scalar_rgb``) last with ``mitsuba``."""
    out = []
    for label, target, width, accel, env in builds(only):
        scene = load(path, defines, target, width, accel, env)
        out.append((label, lambda spp, seed, s=scene: s.render(spp=spp, seed=seed)[..., :3]))
    if mitsuba:
        variant = mitsuba_variant("rgb")
        import mitsuba as mi

        sc = mi.load_file(str(path), **defines)
        out.append((f"Mitsuba 3 {variant}",
                    lambda spp, seed: np.array(mi.render(sc, spp=spp, seed=seed))[..., :3]))
    return out


def measure(fns: list[tuple[str, Any]], ref: np.ndarray, args) -> list[dict]:
    """Every build on one scene: spp, median seconds and CPU seconds, median RMSE."""
    rows = []
    for label, render in fns:
        render(1, 0)  # warm-up: threads, pages, device buffers, Mitsuba's JIT
        t1 = time.perf_counter()
        render(1, 0)
        one = time.perf_counter() - t1
        spp = 2 ** max(0, min(10, round(math.log2(max(args.seconds / one, 1)))))
        render(spp, 0)  # and at that spp (Mitsuba's kernels depend on it)
        rows.append({"build": label, "spp": spp, "wall": [], "cpu": [], "rmse": []})
        print(f"  {label}: {spp} spp", flush=True)
    for k in range(args.repeat):  # the builds take turns, run by run
        for row, (_, render) in zip(rows, fns):
            w, c = time.perf_counter(), time.process_time()
            img = render(row["spp"], k + 1)
            row["wall"].append(time.perf_counter() - w)
            row["cpu"].append(time.process_time() - c)
            row["rmse"].append(rmse(img, ref))
    for row in rows:
        for key in ("wall", "cpu", "rmse"):
            row[key] = statistics.median(row[key])
    return rows


def ptx_note(path: Path, defines: dict[str, int]) -> str:
    """PTX of the scene's render kernel (sm_80), checked by ptxas where one is found."""
    from rdsl.compiler.backends.ptx import emit_ptx, find_ptxas, run_ptxas
    from rdsl.compiler.build import Build
    from rdsl.compiler.targets import ptx_target
    from rdsl.runtime.render.renderer import Scene

    t = time.perf_counter()
    scene = Scene(path, Build.of(ptx_target("sm_80"), "rgb"), accel="bvh", **defines)
    ptx = emit_ptx(scene.kernel_ir(), ptx_target("sm_80"))
    note = f"compiled, not run ({len(ptx) // 1024} KiB of PTX in {time.perf_counter() - t:.0f} s"
    ptxas = find_ptxas("sm_80")
    if ptxas is not None:
        run_ptxas(ptx, "sm_80", ptxas)
        note += ", ptxas ok"
    return note + "; no CUDA GPU here)"


def table(name: str, rows: list[dict], pixels: int, rays: float, ptx: str) -> None:
    first = rows[0]
    fixed = first["rmse"]
    print(f"\n### {name}\n\nfixed RMSE {fixed:.4f} (the first build's at {first['spp']} spp); "
          f"{rays:.2f} rays per path\n")
    head = ("build", "spp", "s/run", "cpu s/run", "paths/s", "Mrays/s", "RMSE",
            "equal-error s", "paths/s vs first", "equal-error vs first")
    print("| " + " | ".join(head) + " |\n|" + "---|" * len(head))
    eq0 = first["wall"] * (first["rmse"] / fixed) ** 2
    for r in rows:
        paths = pixels * r["spp"] / r["wall"]
        eq = r["wall"] * (r["rmse"] / fixed) ** 2
        mrays = "n/a" if math.isnan(rays) or "Mitsuba" in r["build"] else \
            f"{paths * rays / 1e6:.2f}"
        print(f"| {r['build']} | {r['spp']} | {r['wall']:.3f} | {r['cpu']:.3f} | "
              f"{paths / 1e6:.3f}M | {mrays} | {r['rmse']:.4f} | {eq:.3f} | "
              f"{paths / (pixels * first['spp'] / first['wall']):.2f}x | {eq / eq0:.2f}x |")
    print(f"| ptx (sm_80) | {ptx} | | | | | | | | |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=1.0,
                    help="about how long one timed render of each build takes (default 1)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mesh-res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--no-mitsuba", dest="mitsuba", action="store_false",
                    help="leave out the Mitsuba 3 row (pip install mitsuba; libLLVM 19)")
    ap.add_argument("--builds", default="", help="comma-separated targets to run besides "
                    "the first build, e.g. opencl,ptx (default: all)")
    ap.add_argument("--cbox-only", action="store_true", help="leave out the mesh scene")
    args = ap.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    first = builds()[0]
    cbox_ref = read_exr(CBOX.with_name("cbox_ref_rgb.exr"))[..., :3]
    scenes = {"Cornell box (256x256, max_depth 8)": (CBOX, {}, cbox_ref)}
    if not args.cbox_only:
        scenes[f"height field, {2 * (MESH_N - 1) ** 2} triangles ({args.mesh_res}x"
              f"{args.mesh_res}, max_depth 4)"] = (mesh_scene(args.mesh_res), {}, None)
    print(f"{os.cpu_count()} cores; median of {args.repeat} alternated renders of about "
          f"{args.seconds} s each", flush=True)
    for name, (path, defines, ref) in scenes.items():
        print(f"\n{name}", flush=True)
        if ref is None:
            ref = reference(path, args.ref_spp, (first[1], first[3]))
        pixels = ref.shape[0] * ref.shape[1]
        rays = rays_per_path(path, defines, first[1], pixels)
        rows = measure(renderers(path, defines, args.mitsuba, args.builds), ref, args)
        ptx = ptx_note(path, defines) if not args.builds or "ptx" in args.builds else "not asked"
        table(name, rows, pixels, rays, ptx)


if __name__ == "__main__":
    main()
