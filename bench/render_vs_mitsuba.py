"""Render time against error: rdsl and Mitsuba 3 (`llvm_ad_rgb`) on the same scene, in the
same run, on the same machine.

    python bench/render_vs_mitsuba.py [SCENE.xml ...] [--spp 1 4 16 64 256] [--threads 2]
                                      [--target avx512] [--repeat 3] [--plot out/bench.png]

For each spp it prints seconds (median of --repeat runs after a warm-up; the two
renderers take turns, so a shared machine's changing load hits both alike), paths/s and RMSE
against the scene's reference EXR (`<scene>_ref_rgb.exr` beside it, else cbox's naming) for
both renderers, and the ratio.  The equal-error time ratio assumes RMSE ~ 1/sqrt(time):
ratio = (t_rdsl * rmse_rdsl^2) / (t_mitsuba * rmse_mitsuba^2); below 1 means rdsl reaches
the same error sooner.  Mitsuba 3's LLVM variant needs libLLVM; set DRJIT_LIBLLVM_PATH (the
Debian package libllvm19 provides /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
from rdsl.runtime.render.bench import interleaved_medians, rmse

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCENE = ROOT / "examples" / "cbox" / "cbox.xml"
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def reference_for(scene: Path) -> Path | None:
    for name in (f"{scene.stem}_ref_rgb.exr", f"{scene.parent.name}_ref_rgb.exr"):
        if (scene.parent / name).is_file():
            return scene.parent / name
    return None


def rdsl_renderer(scene: Path, threads: int, target: str):
    """The scene loaded and compiled by rdsl, the compile seconds, and a render function."""
    import rdsl

    s = rdsl.load_scene(scene, variant="rgb", target=target)
    t = time.perf_counter()
    s.compile()
    compile_s = time.perf_counter() - t

    def render(spp: int, seed: int) -> np.ndarray:
        return s.render(spp=spp, seed=seed, threads=threads)
    return s, compile_s, render


def mitsuba_renderer(scene: Path, threads: int):
    """A render function of Mitsuba 3's ``llvm_ad_rgb`` variant, or None without it."""
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
    except Exception as e:  # noqa: BLE001 - any failure means: no Mitsuba here
        print(f"Mitsuba 3 llvm_ad_rgb unavailable ({e}); `pip install mitsuba` and "
              "`apt-get install libllvm19`", file=sys.stderr)
        return None
    dr.set_thread_count(threads)
    sc = mi.load_file(str(scene))

    def render(spp: int, seed: int) -> np.ndarray:
        return np.array(mi.render(sc, spp=spp, seed=seed))  # forces evaluation
    return render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", type=Path, default=[DEFAULT_SCENE])
    ap.add_argument("--spp", type=int, nargs="+", default=[1, 4, 16, 64, 256])
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--target", default="host")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--plot", type=Path, default=ROOT / "out" / "render_vs_mitsuba.png")
    args = ap.parse_args()
    from rdsl.runtime.render.image import read_exr

    curves = {}
    for scene in args.scenes:
        ref_path = reference_for(scene)
        ref = read_exr(ref_path)[..., :3] if ref_path else None
        s, compile_s, rd_render = rdsl_renderer(scene, args.threads, args.target)
        mi_render = mitsuba_renderer(scene, args.threads)
        rd, mi = {}, {} if mi_render else None
        for spp in args.spp:
            fns = {"rdsl": lambda seed, spp=spp, r=rd_render: r(spp, seed)}
            if mi_render:
                fns["mitsuba"] = lambda seed, spp=spp, r=mi_render: r(spp, seed)
            res = interleaved_medians(fns, args.repeat)
            rd[spp] = res["rdsl"]
            if mi_render:
                mi[spp] = res["mitsuba"]
        npix = s.desc.sensor.film["width"] * s.desc.sensor.film["height"]
        print(f"\n{scene.name}: {args.threads} threads, rdsl target "
              f"{s.compile().target}, median of {args.repeat} runs; rdsl kernels "
              f"{'from cache' if s.from_cache else f'compiled in {compile_s:.2f} s'}")
        print(f"{'spp':>5} | {'rdsl s':>8} {'Mpath/s':>8} {'RMSE':>8} | {'mitsuba s':>9} "
              f"{'Mpath/s':>8} {'RMSE':>8} | {'time ratio':>10} {'equal-error':>11} "
              f"{'cpu ratio':>9}")
        rows = []
        for spp in args.spp:
            tr, cr, ir = rd[spp]
            er = rmse(ir, ref) if ref is not None else float("nan")
            line = f"{spp:5d} | {tr:8.3f} {npix * spp / tr / 1e6:8.2f} {er:8.4f} |"
            if mi:
                tm, cm, im = mi[spp]
                em = rmse(im, ref) if ref is not None else float("nan")
                eq = (tr * er * er) / (tm * em * em)
                line += f" {tm:9.3f} {npix * spp / tm / 1e6:8.2f} {em:8.4f} | {tr / tm:10.2f} " \
                        f"{eq:11.2f} {cr / cm:9.2f}"
                rows.append((spp, tr, er, tm, em))
            else:
                rows.append((spp, tr, er, None, None))
            print(line)
        curves[scene.name] = rows
    print("\ntime ratio = rdsl seconds / Mitsuba seconds at the same spp; equal-error = the "
          "ratio of times to reach the same RMSE (below 1: rdsl is faster); cpu ratio = the "
          "ratio of CPU seconds (all threads), which a loaded machine hardly changes")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("(matplotlib is not installed: no plot; pip install -e '.[bench]')")
        return
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name, rows in curves.items():
        ax.loglog([r[1] for r in rows], [r[2] for r in rows], "o-", label=f"rdsl {name}")
        if rows[0][3] is not None:
            ax.loglog([r[3] for r in rows], [r[4] for r in rows], "s--",
                      label=f"Mitsuba 3 {name}")
    ax.set_xlabel("render time (s)")
    ax.set_ylabel("RMSE vs reference")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.plot, dpi=120, bbox_inches="tight")
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
