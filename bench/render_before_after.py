"""Warm render time of two rdsl checkouts, alternated: each scene rendered by the "before"
package and by this one in turn, each run a process of its own that renders once untimed
(its kernels built or read from its own cache) and then ``--renders`` times, timed; the
medians of the runs' medians, wall and CPU seconds (every thread's), and their ratios.

    python bench/render_before_after.py BASE_PKG_PARENT [NAME ...] [--spp 64] [--repeat 2]

BASE_PKG_PARENT is a folder holding ``rdsl`` (a link to the other checkout), put first on
PYTHONPATH for the "before" runs (see bench/ttfp_before_after.py).  Each checkout keeps its
kernels in a cache folder of its own under out/render_before_after/, so neither reads the
other's, and the full tier is built before timing (``RDSL_QUICK=0``).  The images of the
two must be the same bit for bit for a change that should not alter them: the table says
whether they are.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from scene_set import all_scenes, scene_defaults

ROOT = Path(__file__).resolve().parents[1]

# run in the child: render, time, print one JSON line
CHILD = r"""
import hashlib, json, sys, time
import numpy as np
import rdsl
path, spp, n, defaults = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), json.loads(sys.argv[4])
scene = rdsl.load_scene(path, **defaults)
img = np.ascontiguousarray(scene.render(spp=spp, seed=1), np.float32)
walls, cpus = [], []
for _ in range(n):
    t, c = time.perf_counter(), time.process_time()
    scene.render(spp=spp, seed=1)
    walls.append(time.perf_counter() - t)
    cpus.append(time.process_time() - c)
print(json.dumps({"wall": float(np.median(walls)), "cpu": float(np.median(cpus)),
                  "hash": hashlib.sha256(img.tobytes()).hexdigest()}))
"""


def run(path: Path, spp: int, renders: int, pythonpath: str | None, cache: Path) -> dict:
    env = dict(os.environ, RDSL_CACHE_DIR=str(cache), RDSL_QUICK="0")
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    else:
        env.pop("PYTHONPATH", None)
    r = subprocess.run([sys.executable, "-c", CHILD, str(path), str(spp), str(renders),
                        json.dumps(scene_defaults(path))], env=env, capture_output=True,
                       text=True, check=False)
    if r.returncode != 0:
        sys.exit(f"{path.name}: the render failed:\n{r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", type=Path)
    ap.add_argument("names", nargs="*")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--renders", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    scenes = all_scenes()
    out = ROOT / "out" / "render_before_after"
    caches = {k: out / hashlib.sha256(str(p).encode()).hexdigest()[:12]
              for k, p in (("before", args.base.resolve()), ("after", ROOT))}
    print(f"{args.spp} spp, median of {args.renders} renders per run, {args.repeat} runs each, "
          "alternated")
    print(f"{'scene':<26} {'before s':>9} {'after s':>8} {'ratio':>6} | {'before cpu':>10} "
          f"{'after cpu':>9} {'ratio':>6} | same image")
    ratios = []
    for name in args.names or list(scenes):
        runs: dict[str, list[dict]] = {"before": [], "after": []}
        for _ in range(args.repeat):
            runs["before"].append(run(scenes[name], args.spp, args.renders, str(args.base),
                                      caches["before"]))
            runs["after"].append(run(scenes[name], args.spp, args.renders, None,
                                     caches["after"]))
        (wb, cb), (wa, ca) = ([statistics.median(x[m] for x in runs[k]) for m in ("wall", "cpu")]
                              for k in ("before", "after"))
        same = runs["before"][0]["hash"] == runs["after"][0]["hash"]
        ratios.append(ca / cb)
        print(f"{name:<26} {wb:9.3f} {wa:8.3f} {wa / wb:6.2f} | {cb:10.3f} {ca:9.3f} "
              f"{ca / cb:6.2f} | {'yes' if same else 'NO'}", flush=True)
    gm = statistics.geometric_mean(ratios)
    print(f"{'geometric mean, CPU':<26} {'':>9} {'':>8} {'':>6} | {'':>10} {'':>9} {gm:6.2f}")


if __name__ == "__main__":
    main()
