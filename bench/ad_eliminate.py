"""Graph elimination (compiler/passes/eliminate.py): what the reverse sweeps keep of their
forward parts, with and without it, and the time and peak RSS of ``scene.backward``.

"Tape bytes per lane per bounce" = 4 x the number of distinct non-constant values that the
sweep of one iteration of the bounce loop's adjoint reads from that iteration's forward
part (8 for a 64-bit integer), counted on the IR after ``eliminate`` and DCE
(compiler/passes/ad_tape.py); per call for a kernel's own body.  Peak RSS is that of a
fresh process that loads the Cornell box and runs one ``backward`` (the adjoint kernel
compiled, or loaded from the cache, in it); times are medians of alternated runs.
Not a test: run it by hand.

    python bench/ad_eliminate.py [--res 64] [--spp 16] [--repeat 3] [--threshold 10]
"""

from __future__ import annotations

import argparse
import io
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / ".." / "shared" / "scenes" / "cbox" / "cbox.xml"
NAMES = ["red.reflectance.value", "green.reflectance.value", "light.emitter.radiance.value"]
BSDFS = [("diffuse", "eval"), ("roughconductor", "eval"), ("roughplastic", "eval"),
         ("principled", "eval"), ("roughdielectric", "sample")]


def tapes(module_fn, build) -> list:
    """The tape of each sweep of the function ``module_fn()`` compiles for ``build``."""
    from rdsl.compiler.driver import pipeline, run_passes
    from rdsl.compiler.passes.ad_tape import tape

    module, name, spec = module_fn()
    stop = "eliminate" if build.eliminate else "ad_reverse"
    run_passes(module, pipeline(build, spec), out=io.StringIO(), stop_after=stop)
    return tape(module.functions[name])


def cbox_module(scene):
    from rdsl.compiler.driver import frontend
    from rdsl.compiler.passes.specialize import parameter_slots

    spec = parameter_slots(scene.scene_spec, scene.build.model)[0]
    return lambda: (frontend(scene.kernel_src, "cbox.rdsl", scene.search_paths),
                    "render_sample", spec)


def tape_table(threshold: int) -> None:
    import rdsl
    from rdsl.compiler.build import Build
    from rdsl.compiler.driver import frontend

    print("tape bytes per lane: per iteration of a loop's adjoint (the path tracer's "
          "bounce loop: per bounce), per call of a kernel's own body")
    print(f"{'kernel':<32} {'sweep':<10} {'bytes/lane, off':>16} {'eliminate':>10} "
          f"{'ratio':>6}")
    rows = []
    for depth in (3, -1):
        scene = rdsl.load_scene(CBOX, res=16, max_depth=depth)
        scene.use_generic()
        scene.compile()
        rows.append((f"cbox render_sample d={depth}", cbox_module(scene)))
    for name, fn in BSDFS:
        path = ROOT / "stdlib" / "bsdf" / f"{name}.rdsl"
        rows.append((f"{name}.{fn}", lambda p=path, n=f"{name}.{fn}": (frontend(p), n, None)))
    for label, make in rows:
        off = tapes(make, Build.of("host", "rgb", ad="reverse"))
        on = tapes(make, Build.of("host", "rgb", ad="reverse", eliminate=threshold))
        for a, b in zip(off, on):
            what = f"loop@{a.line}" if a.kind == "loop" else "per call"
            print(f"{label:<32} {what:<10} {a.bytes:>16} {b.bytes:>10} "
                  f"{b.bytes / max(a.bytes, 1):>6.2f}")


def child(args) -> None:
    """One backward in this process: prints its times and peak RSS as JSON."""
    import numpy as np
    import rdsl

    scene = rdsl.load_scene(CBOX, res=args.res, max_depth=args.depth)
    d = np.random.default_rng(0).standard_normal((args.res, args.res, 3))
    el = args.threshold if args.on else False
    t = time.perf_counter()
    g = scene.backward(d, NAMES, spp=args.spp, seed=1, eliminate=el)
    first = time.perf_counter() - t
    times = []
    for _ in range(args.repeat):
        t = time.perf_counter()
        scene.backward(d, NAMES, spp=args.spp, seed=1, eliminate=el)
        times.append(time.perf_counter() - t)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"first": first, "median": statistics.median(times), "rss": rss,
                      "grad": [float(x) for v in g.values() for x in v]}))


def run_child(args, on: bool) -> dict:
    cmd = [sys.executable, __file__, "--child", "--res", str(args.res), "--spp",
           str(args.spp), "--repeat", "1", "--threshold", str(args.threshold),
           "--depth", str(args.depth)] + (["--on"] if on else [])
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threshold", type=int, default=10)
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--child", action="store_true")
    ap.add_argument("--on", action="store_true")
    args = ap.parse_args()
    if args.child:
        child(args)
        return 0
    tape_table(args.threshold)
    runs: dict[bool, list[dict]] = {False: [], True: []}
    for _ in range(args.repeat):  # alternated, each in a fresh process
        for on in (False, True):
            runs[on].append(run_child(args, on))
    print(f"\nCornell box {args.res}x{args.res}, {args.spp} spp, max_depth {args.depth}, "
          f"scene.backward of {len(NAMES)} colour parameters, {args.repeat} fresh "
          "processes each")
    print(f"{'eliminate':<10} {'backward s':>10} {'peak RSS MiB':>13}")
    for on in (False, True):
        r = runs[on]
        print(f"{'on' if on else 'off':<10} {statistics.median(x['median'] for x in r):>10.3f} "
              f"{statistics.median(x['rss'] for x in r):>13.0f}")
    a, b = runs[False][0]["grad"], runs[True][0]["grad"]
    rel = max(abs(x - y) / max(abs(x), 1e-6) for x, y in zip(a, b))
    print(f"largest relative difference of the gradients, off vs on: {rel:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
