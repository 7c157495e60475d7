"""What `roughplastic` costs against `plastic`: the same scene rendered with each.

    python bench/roughplastic_cost.py [--res 128] [--spp 16] [--repeat 5] [--threads 2]
                                      [--mitsuba] [--mitsuba-variant llvm_ad_rgb]

The scene is issue 11's worst case: a ground plane of the material, lit by a sphere light
and a constant environment, with a diffuse sphere on it (path tracer, max_depth 6, box
filter).  Both materials are compiled first (kernels warm), then rendered in turn, one run
each per repeat, so that a change in the shared machine's load hits both alike; the script
prints the median seconds of each and their ratio (the bar: roughplastic <= 1.2 x plastic),
and each build's cold compile time (roughplastic's includes computing its tables).

With ``--mitsuba`` it renders the same two scenes with Mitsuba 3 in the same run
(``llvm_ad_rgb`` by default: it needs libLLVM, ``DRJIT_LIBLLVM_PATH``; the scalar variants
work without, slowly) and prints rdsl's time over Mitsuba's for each material.  With
``--image-spp N`` it also renders both scenes at 32 x 32 and N spp with rdsl and with Mitsuba
(four renders of N / 4 spp, for its standard error) and prints the relative difference of the
images' means.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

MATERIALS = {
    "plastic": '<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.2, 0.4, 0.7"/>'
               '</bsdf>',
    "roughplastic": '<bsdf type="roughplastic"><string name="distribution" value="ggx"/>'
                    '<float name="alpha" value="0.3"/>'
                    '<rgb name="diffuse_reflectance" value="0.2, 0.4, 0.7"/></bsdf>',
}

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world">
            <lookat origin="0, -6, 3" target="0, 0, 0.5" up="0, 0, 1"/>
        </transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/><rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle"><transform name="to_world"><scale value="10"/></transform>
        {material}</shape>
    <shape type="sphere"><point name="center" value="0, 0, 1"/><float name="radius" value="1"/>
        <bsdf type="diffuse"/></shape>
    <shape type="sphere"><point name="center" value="3, -2, 5"/>
        <float name="radius" value="0.5"/>
        <emitter type="area"><rgb name="radiance" value="40, 40, 40"/></emitter></shape>
    <emitter type="constant"><rgb name="radiance" value="0.3, 0.3, 0.3"/></emitter>
</scene>
"""


def write_scenes(folder: Path, res: int, spp: int) -> dict[str, Path]:
    out = {}
    for name, material in MATERIALS.items():
        out[name] = folder / f"{name}.xml"
        out[name].write_text(SCENE.format(res=res, spp=spp, material=material))
    return out


def medians(fns: dict[str, Callable[[int], object]], repeat: int) -> dict[str, float]:
    """Median wall seconds of each function, after one warm-up call each, in turns."""
    for fn in fns.values():
        fn(0)
    times: dict[str, list[float]] = {name: [] for name in fns}
    for k in range(repeat):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn(k + 1)
            times[name].append(time.perf_counter() - t)
    return {name: statistics.median(ts) for name, ts in times.items()}


def rdsl_renders(scenes: dict[str, Path], spp: int, threads: int) -> dict[str, Callable]:
    import rdsl

    out = {}
    for name, path in scenes.items():
        s = rdsl.load_scene(path, variant="rgb")
        t = time.perf_counter()
        s.compile()
        how = "from cache" if s.from_cache else f"compiled in {time.perf_counter() - t:.2f} s"
        print(f"  rdsl {name}: kernels {how}")
        out[name] = lambda seed, s=s: s.render(spp=spp, seed=seed, threads=threads)
    return out


def mitsuba_renders(scenes: dict[str, Path], spp: int, threads: int, variant: str
                    ) -> dict[str, Callable] | None:
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001 - any failure: no Mitsuba here
        print(f"Mitsuba 3 {variant} unavailable ({e}); for llvm_ad_rgb install libllvm19 "
              "and set DRJIT_LIBLLVM_PATH, or pass --mitsuba-variant scalar_rgb",
              file=sys.stderr)
        return None
    if hasattr(dr, "set_thread_count"):
        dr.set_thread_count(threads)
    import numpy as np

    out = {}
    for name, path in scenes.items():
        sc = mi.load_file(str(path))
        out[name] = lambda seed, sc=sc: np.array(mi.render(sc, spp=spp, seed=seed))
    return out


def image_check(spp: int, variant: str) -> None:
    """The mean of rdsl's image against Mitsuba's, per material, at 32 x 32 and ``spp``."""
    import numpy as np
    import rdsl

    try:
        import mitsuba as mi

        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001 - any failure: no Mitsuba here
        print(f"Mitsuba 3 {variant} unavailable ({e})", file=sys.stderr)
        return
    with tempfile.TemporaryDirectory() as tmp:
        for name, path in write_scenes(Path(tmp), 32, spp).items():
            ours = np.asarray(rdsl.load_scene(path).render(spp=spp, seed=1))[..., :3]
            scene = mi.load_file(str(path))
            theirs = np.stack([np.array(mi.render(scene, spp=spp // 4, seed=s))[..., :3]
                               for s in range(4)]).astype(np.float64)
            mean = theirs.mean()
            err = theirs.mean(axis=(1, 2, 3)).std(ddof=1) / 2 / mean
            print(f"image mean, {name}: rdsl {ours.mean():.5f}, Mitsuba 3 ({variant}) "
                  f"{mean:.5f}: {(ours.mean() - mean) / mean:+.1e} relative (Mitsuba's "
                  f"standard error {err:.1e})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--mitsuba", action="store_true", help="time Mitsuba 3 on the same scenes")
    ap.add_argument("--mitsuba-variant", default="llvm_ad_rgb")
    ap.add_argument("--image-spp", type=int, default=0,
                    help="compare image means with Mitsuba at this spp (0: no)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scenes = write_scenes(Path(tmp), args.res, args.spp)
        print(f"{args.res}x{args.res}, {args.spp} spp, {args.threads} threads, median of "
              f"{args.repeat} alternating runs")
        fns = {f"rdsl {k}": f for k, f in rdsl_renders(scenes, args.spp, args.threads).items()}
        if args.mitsuba:
            theirs = mitsuba_renders(scenes, args.spp, args.threads, args.mitsuba_variant)
            if theirs:
                fns.update({f"mitsuba {k}": f for k, f in theirs.items()})
        t = medians(fns, args.repeat)
    for name, sec in t.items():
        print(f"  {name:22s} {sec:8.3f} s")
    print(f"rdsl roughplastic / plastic: {t['rdsl roughplastic'] / t['rdsl plastic']:.2f}")
    for m in MATERIALS:
        if f"mitsuba {m}" in t:
            print(f"rdsl / Mitsuba 3 ({args.mitsuba_variant}), {m}: "
                  f"{t[f'rdsl {m}'] / t[f'mitsuba {m}']:.2f}")
    if "mitsuba roughplastic" in t:
        print(f"Mitsuba roughplastic / plastic: "
              f"{t['mitsuba roughplastic'] / t['mitsuba plastic']:.2f}")
    if args.image_spp:
        image_check(args.image_spp, args.mitsuba_variant)


if __name__ == "__main__":
    main()
