"""Reverse-mode AD on the Cornell box: what the adjoint stores per lane, and the time of
``scene.backward`` against a plain render and against forward mode (``scene.gradient``, one
derivative render per parameter component), for a fixed depth and for max_depth -1 with
Russian roulette.  Times are medians of alternated runs (the kernels compiled first).
Not a test: run it by hand.

    python bench/ad_reverse.py [--res 64] [--spp 16] [--repeat 3]
"""

from __future__ import annotations

import argparse
import io
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import rdsl
from rdsl.compiler.build import Build
from rdsl.compiler.driver import frontend, pipeline, run_passes
from rdsl.compiler.ir import F32, Op
from rdsl.compiler.passes.specialize import parameter_slots
from rdsl.runtime.render.backward import TAPE

CBOX = Path(__file__).resolve().parents[1] / ".." / "shared" / "scenes" / "cbox" / "cbox.xml"
NAMES = ["red.reflectance.value", "green.reflectance.value", "light.emitter.radiance.value"]


def adjoint_state(scene) -> tuple[int, int, int]:
    """(bytes per lane the bounce loop's adjoint carries, bytes per lane stored per bounce,
    gradient bytes per row) of the scene's reverse kernel, read from its IR."""
    scene.use_generic()
    scene.compile()
    spec = parameter_slots(scene.scene_spec, scene.build.model)[0]
    build = Build(scene.build.target, scene.build.model, "reverse", tape=TAPE)
    module = frontend(scene.kernel_src, "cbox.rdsl", scene.search_paths)
    run_passes(module, pipeline(build, spec), out=io.StringIO(), stop_after="ad_reverse")
    fn = module.functions["render_sample"]
    loops = [i for i in fn.walk() if i.op is Op.LOOP and i.regions[0].args
             and i.regions[0].args[0].name == "ad.k"]
    carried = max(sum(4 if a.type == F32 or a.type.bits <= 32 else 8
                      for a in i.regions[0].args) for i in loops)
    stores = sum(1 for i in fn.walk() if i.op is Op.STORE and i.operands[0].name == "ad_tape")
    return carried, stores * 4, scene.prm.size * 4


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def measure(scene, args) -> tuple[dict[str, float], float]:
    """Median seconds of render, backward and forward-mode gradient; the first backward's."""
    d = np.random.default_rng(0).standard_normal((args.res, args.res, 3))
    t0 = timed(lambda: scene.backward(d, NAMES, spp=args.spp, seed=1))  # compiles
    scene.gradient(NAMES[:1], d, spp=1, seed=1)
    times: dict[str, list[float]] = {"render": [], "backward": [], "forward": []}
    for _ in range(args.repeat):
        times["render"].append(timed(lambda: scene.render(spp=args.spp, seed=1)))
        times["backward"].append(timed(lambda: scene.backward(d, NAMES, spp=args.spp,
                                                              seed=1)))
        times["forward"].append(timed(lambda: scene.gradient(NAMES, d, spp=args.spp,
                                                             seed=1)))
    return {k: statistics.median(v) for k, v in times.items()}, t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    print(f"Cornell box {args.res}x{args.res}, {args.spp} spp, {len(NAMES)} colour parameters")
    rows = []
    for depth in (3, 8, -1):
        scene = rdsl.load_scene(CBOX, res=args.res, max_depth=depth)
        if depth == 3:
            carried, taped, grad = adjoint_state(scene)
            print(f"adjoint of the bounce loop: {carried} bytes per lane carried (k, the "
                  f"adjoints of the carried values), {taped} bytes per lane per bounce "
                  f"stored (the carried state and the forward values the sweep reads, "
                  f"for each of the first {TAPE} "
                  f"bounces, {(TAPE + 1) * taped} bytes per lane's tape row); gradient rows: "
                  f"{grad} bytes each, 64 per thread")
        rows.append((depth, *measure(scene, args)))
    print(f"{'max_depth':>9} {'render s':>9} {'backward s':>10} {'bwd/render':>10} "
          f"{'fwd-mode s':>10} {'fwd/bwd':>8}")
    for depth, med, _ in rows:
        print(f"{depth:>9} {med['render']:>9.3f} {med['backward']:>10.3f} "
              f"{med['backward'] / med['render']:>10.1f} {med['forward']:>10.3f} "
              f"{med['forward'] / med['backward']:>8.1f}")
    print(f"first backward (compiles the adjoint kernel, or loads it from the cache): "
          f"{rows[0][2]:.1f} s")
    print(f"peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
