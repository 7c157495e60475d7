"""What each colour model costs, relative to rgb: rdsl and Mitsuba 3 in the same run.

    python bench/variant_cost.py [SCENE.xml ...] [--spp 64] [--threads 2] [--target avx512]
                                 [--repeat 5] [--variants mono rgb spectral]

For each scene and variant it renders with rdsl and with Mitsuba 3's matching LLVM variant
(``llvm_ad_<variant>``), taking turns run by run so that a shared machine's load hits both
alike, and prints the median seconds and each renderer's cost relative to its own rgb
render.  The default scenes are the Cornell box and bench/scenes/materials.xml (a rough
copper sphere with tabulated complex IOR and a glass sphere).  Mitsuba 3's LLVM variants
need libLLVM: DRJIT_LIBLLVM_PATH is set to Debian's libllvm19 unless already set.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = [ROOT / "examples" / "cbox" / "cbox.xml",
          ROOT / "bench" / "scenes" / "materials.xml"]
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")


def rdsl_renderer(scene: Path, variant: str, target: str, threads: int, spp: int):
    import rdsl

    s = rdsl.load_scene(scene, variant=variant, target=target)
    s.compile()
    return lambda seed: s.render(spp=spp, seed=seed, threads=threads)


def mitsuba_renderer(scene: Path, variant: str, threads: int, spp: int):
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(f"llvm_ad_{variant}")
    except Exception as e:  # noqa: BLE001 - any failure means: no Mitsuba here
        print(f"Mitsuba 3 llvm_ad_{variant} unavailable ({e})", file=sys.stderr)
        return None
    dr.set_thread_count(threads)
    sc = mi.load_file(str(scene))

    def render(seed: int) -> np.ndarray:
        mi.set_variant(f"llvm_ad_{variant}")
        return np.array(mi.render(sc, spp=spp, seed=seed))  # forces evaluation

    return render


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", type=Path, default=SCENES)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--target", default="host")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--variants", nargs="+", default=["mono", "rgb", "spectral", "mono_polarized",
                                                      "spectral_polarized"])
    args = ap.parse_args()
    if "rgb" not in args.variants:
        args.variants.insert(0, "rgb")
    for scene in args.scenes:
        runs = {}
        for v in args.variants:
            runs[("rdsl", v)] = rdsl_renderer(scene, v, args.target, args.threads, args.spp)
            mi = mitsuba_renderer(scene, v, args.threads, args.spp)
            if mi is not None:
                runs[("mitsuba", v)] = mi
        times: dict[tuple[str, str], list[float]] = {k: [] for k in runs}
        for k, fn in runs.items():
            fn(0)  # warm-up: compilation, caches, page faults
        for rep in range(args.repeat):
            for k, fn in runs.items():
                t = time.perf_counter()
                fn(rep + 1)
                times[k].append(time.perf_counter() - t)
        med = {k: statistics.median(ts) for k, ts in times.items()}
        print(f"\n{scene.name}: {args.spp} spp, {args.threads} threads, rdsl target "
              f"{args.target}, median of {args.repeat} alternating runs")
        print(f"{'variant':>20} | {'rdsl s':>8} {'vs rgb':>7} | {'mitsuba s':>9} {'vs rgb':>7}"
              f" | {'rdsl/mitsuba':>12}")
        for v in args.variants:
            r = med[("rdsl", v)]
            line = f"{v:>20} | {r:8.3f} {r / med[('rdsl', 'rgb')]:7.2f} |"
            m = med.get(("mitsuba", v))
            if m is not None:
                line += (f" {m:9.3f} {m / med[('mitsuba', 'rgb')]:7.2f} | {r / m:12.2f}")
            print(line)
    print("\nvs rgb = the variant's render time over the same renderer's rgb render time")


if __name__ == "__main__":
    main()
