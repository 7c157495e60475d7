"""CPU seconds of ``scene.backward`` alone for each CPU target of the adjoint kernel (issue
13: is a narrower or cheaper build of the adjoint kernel faster than the host's widest?).

The scene (the Cornell box of bench/ad_vs_mitsuba.py, 128x128, 16 spp, max_depth 8) renders
with the host target as usual; only the adjoint twin's build is swapped for the target
named (``avx512w8``: the AVX-512 features, 32 vector registers and mask registers, at 8
lanes).  Each target runs in a fresh process (one compile or cache load each), the targets
alternated, ``--rounds`` times; each run prints the median of ``--calls`` calls of
``backward`` (``time.process_time``: CPU seconds of both threads; the shared machine moves
wall time more) and the gradient, which must not depend on the target beyond rounding.
``--speed N`` runs LLVM's ON pipeline instead of O3 (its own kernel cache directory, so a
cached O3 kernel is not reused).  Not a test: run it by hand.

    python bench/ad_backward_width.py [avx512 avx512w8 avx2 sse4] [--calls 7] [--rounds 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
KEY = "red.reflectance.value"


def _target(name: str):
    from rdsl.compiler.targets import TARGETS, Target

    if name == "avx512w8":
        wide = TARGETS["avx512"]
        return Target("avx512w8", 8, wide.cpu, wide.features, wide.requires, 256)
    return TARGETS[name]


def _speed(level: int) -> None:
    """LLVM's O``level`` pipeline for the kernels (instead of O3)."""
    import rdsl.compiler.backends.llvm as backend

    full = backend.optimized_module

    def optimized_module(module, target, speed=3, quick=False):
        return full(module, target, level if speed == 3 else speed, quick)

    backend.optimized_module = optimized_module


def one(name: str, calls: int, speed: int) -> dict:
    """In this process: ``calls`` timed calls of ``backward`` with the adjoint on ``name``."""
    import rdsl
    from rdsl.runtime.render.backward import TAPE
    from rdsl.runtime.render.differentiable import ad_twin

    if speed != 3:
        _speed(speed)
    scene = rdsl.load_scene(CBOX, res=128, spp=16, max_depth=8)
    target = scene.render(spp=32, seed=10_000).astype(np.float64)
    twin = ad_twin(scene, "reverse", 0, TAPE)  # the twin backward will take
    twin.build = dataclasses.replace(twin.build, target=_target(name))
    scene.params[KEY] = np.full(3, 0.5, np.float32)
    d = 2.0 * (scene.render(seed=0) - target) / target.size
    t = time.perf_counter()
    grad = scene.backward(d, [KEY], seed=0)[KEY]
    first = time.perf_counter() - t
    cpu = []
    for i in range(calls):
        scene.render(seed=i)  # as the benchmark's loop: backward uses its film weights
        t = time.process_time()
        scene.backward(d, [KEY], seed=i)
        cpu.append(time.process_time() - t)
    return {"target": name, "width": _target(name).width, "first_s": first,
            "cpu_s": float(np.median(cpu)), "grad": grad.tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("targets", nargs="*", default=["avx512", "avx512w8", "avx2", "sse4"])
    ap.add_argument("--calls", type=int, default=7)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--speed", type=int, default=3)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args.targets[0], args.calls, args.speed)))
        return
    env = dict(os.environ)
    if args.speed != 3:
        env["RDSL_CACHE_DIR"] = tempfile.mkdtemp(prefix=f"rdsl-O{args.speed}-")
    runs: dict[str, list[float]] = {}
    for _ in range(args.rounds):
        for name in args.targets:
            out = subprocess.run([sys.executable, __file__, name, "--one", "--calls",
                                  str(args.calls), "--speed", str(args.speed)], env=env,
                                 capture_output=True, text=True, check=True).stdout
            r = json.loads(out.strip().splitlines()[-1])
            runs.setdefault(name, []).append(r["cpu_s"])
            print(f"{name:9} width {r['width']:2}  backward {r['cpu_s']:.3f} CPU s  "
                  f"(first call {r['first_s']:.1f} s)  grad {np.round(r['grad'], 7)}",
                  flush=True)
    for name, cpu in runs.items():
        print(f"{name:9} median of runs {np.median(cpu):.3f} CPU s  runs {[round(x, 3) for x in cpu]}")


if __name__ == "__main__":
    main()
