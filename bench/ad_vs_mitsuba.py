"""Inverse rendering, rdsl against Mitsuba 3 ``prb``: recover the Cornell box's red-wall albedo
with the same spp, iteration count, start, optimizer (Adam, same rate) and loss (the mean
squared error against a target the renderer itself rendered at 8x the spp; the gradient from
other samples than the image's, as Mitsuba does), alternating the two renderers on one
machine, each in a process of its own (for its peak RSS).

    python bench/ad_vs_mitsuba.py [--res 128] [--spp 16] [--max-depth 8] [--iterations 20]
                                  [--rounds 2] [--cold] [--eliminate]

Per run: the median seconds per iteration (render, loss, gradient, Adam step; excluding the
first), the first iteration's seconds (which compiles the differentiated kernels, or loads
them from the renderer's kernel cache), the peak RSS of the process and the recovered
albedo.  ``--cold`` adds a first round with empty kernel caches (rdsl: a fresh
``$RDSL_CACHE_DIR``; Mitsuba: a fresh ``$HOME``, under which Dr.Jit keeps ``~/.drjit``).
Before the measured rounds each renderer runs 2 iterations once, unmeasured, which fills
its default kernel cache (a warm run loads its kernels from there), and the benchmark waits
for the full-tier builds rdsl left running in the background.
Mitsuba runs ``llvm_ad_rgb`` (``DRJIT_LIBLLVM_PATH``, default libLLVM 19 as Debian installs
it).  Not a test: run it by hand (docs/ad.md has the numbers).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
KEY = "red.reflectance.value"
LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
# the gradient's samples are not the image's (as Mitsuba's `seed_grad`, which mi.render
# derives from `seed` and refuses to equal it): with the same samples, the gradient of
# the squared error would be biased by the covariance of the image's noise and the
# gradient's
GRAD_SEED = 1 << 20


def run_rdsl(args) -> dict:
    import rdsl

    scene = rdsl.load_scene(CBOX, res=args.res, spp=args.spp, max_depth=args.max_depth)
    truth = scene.params[KEY]
    target = scene.render(spp=8 * args.spp, seed=10_000).astype(np.float64)
    opt = rdsl.optim.Adam(lr=args.lr)
    opt[KEY] = np.full(3, 0.5, np.float32)
    times, losses = [], []
    for it in range(args.iterations):
        t = time.perf_counter()
        scene.params[KEY] = opt[KEY]
        img = scene.render(seed=it)
        diff = img - target
        losses.append(float(np.mean(diff * diff)))
        grads = scene.backward(2.0 * diff / diff.size, [KEY], seed=GRAD_SEED + it,
                               eliminate=args.eliminate)
        opt.step(grads)
        opt.clamp(KEY, 0.0, 1.0)
        times.append(time.perf_counter() - t)
    return {"times": times, "losses": losses, "got": opt[KEY].tolist(),
            "truth": np.asarray(truth).tolist()}


def run_mitsuba(args) -> dict:
    os.environ.setdefault("DRJIT_LIBLLVM_PATH", LIBLLVM)
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    scene = mi.load_file(str(CBOX), res=args.res, spp=args.spp, max_depth=args.max_depth)
    integrator = mi.load_dict({"type": "prb", "max_depth": args.max_depth})
    params = mi.traverse(scene)
    truth = np.array(params[KEY]).reshape(-1)
    target = mi.render(scene, spp=8 * args.spp, seed=10_000, integrator=integrator)
    dr.eval(target)
    opt = mi.ad.Adam(lr=args.lr)
    opt[KEY] = mi.Color3f(0.5)
    params.update(opt)
    times, losses = [], []
    for it in range(args.iterations):
        t = time.perf_counter()
        img = mi.render(scene, params, spp=args.spp, seed=it, integrator=integrator)
        loss = dr.mean(dr.square(img - target), axis=None)
        dr.backward(loss)
        opt.step()
        opt[KEY] = dr.clip(opt[KEY], 0.0, 1.0)
        params.update(opt)
        losses.append(float(np.array(loss).reshape(-1)[0]))
        dr.sync_thread()
        times.append(time.perf_counter() - t)
    return {"times": times, "losses": losses,
            "got": np.array(opt[KEY]).reshape(-1).tolist(), "truth": truth.tolist()}


def child(args) -> int:
    out = (run_rdsl if args.child == "rdsl" else run_mitsuba)(args)
    out["rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print("RESULT " + json.dumps(out))
    return 0


def spawn(who: str, args, cold: bool, iterations: int | None = None) -> dict:
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=os.environ.get("DRJIT_LIBLLVM_PATH", LIBLLVM))
    with tempfile.TemporaryDirectory(prefix="adbench-") as tmp:
        if cold:
            env["RDSL_CACHE_DIR" if who == "rdsl" else "HOME"] = tmp
        cmd = [sys.executable, __file__, "--child", who, "--res", str(args.res), "--spp",
               str(args.spp), "--max-depth", str(args.max_depth), "--iterations",
               str(iterations or args.iterations), "--lr", str(args.lr),
               *["--eliminate"] * args.eliminate]
        t = time.perf_counter()
        p = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - t
    line = next((x for x in p.stdout.splitlines() if x.startswith("RESULT ")), None)
    if p.returncode or line is None:
        raise SystemExit(f"{who} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}")
    r = json.loads(line[len("RESULT "):])
    r.update(who=who, cold=cold, wall=wall, per_iter=statistics.median(r["times"][1:]),
             first=r["times"][0])
    return r


def wait_for_background_builds(limit: float = 300.0) -> None:
    """Wait until no full-tier build that an rdsl process left running is still running
    (runtime/render/tier_up.py: a build outlives its process).  Otherwise, after a change of
    the compiler (new cache keys), the first warm run would render with the quick tier
    while the build competes for the cores (measured: 0.47 s/iter against 0.17)."""
    t = time.perf_counter()
    while time.perf_counter() - t < limit:
        running = False
        for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
            try:
                running = b"rdsl.runtime.render.tier_up" in cmdline.read_bytes()
            except OSError:
                continue
            if running:
                break
        if not running:
            return
        time.sleep(0.5)


def table(runs: list[dict]) -> None:
    print(f"{'renderer':<8} {'cache':<5} {'s/iter':>7} {'first s':>8} {'RSS MiB':>8} "
          f"{'process s':>9} {'loss 0 -> last':>20}  recovered (truth)")
    for r in runs:
        got = ", ".join(f"{x:.3f}" for x in r["got"])
        truth = ", ".join(f"{x:.3f}" for x in r["truth"])
        print(f"{r['who']:<8} {'cold' if r['cold'] else 'warm':<5} {r['per_iter']:>7.3f} "
              f"{r['first']:>8.2f} {r['rss_mib']:>8.0f} {r['wall']:>9.1f} "
              f"{r['losses'][0]:>9.2e} -> {r['losses'][-1]:.2e}  {got} ({truth})")


def summary(runs: list[dict]) -> None:
    def med(who, key):
        return statistics.median(r[key] for r in runs if r["who"] == who and not r["cold"])

    rows = [("s/iter (median)", "per_iter", "<= 0.5"), ("first iteration s", "first", "< 3 s"),
            ("peak RSS MiB", "rss_mib", "<= 1")]
    print(f"\nwarm runs, medians: {'':>10} {'rdsl':>8} {'Mitsuba':>8} {'ratio':>6}  bar")
    for label, key, bar in rows:
        a, b = med("rdsl", key), med("mitsuba", key)
        print(f"{label:<30} {a:>8.3f} {b:>8.3f} {a / b:>6.2f}  {bar}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--eliminate", action="store_true", help="rdsl's backward with the "
                    "eliminate pass (threshold 10)")
    ap.add_argument("--child", choices=("rdsl", "mitsuba"))
    args = ap.parse_args()
    if args.child:
        return child(args)
    print(f"Cornell box {args.res}x{args.res}, {args.spp} spp, max_depth {args.max_depth}, "
          f"{args.iterations} iterations of Adam (lr {args.lr}) on {KEY}, MSE loss; "
          f"{os.cpu_count()} cores")
    runs = []
    for who in ("rdsl", "mitsuba"):  # fill the default kernel caches (not measured)
        spawn(who, args, False, iterations=2)
    wait_for_background_builds()
    schedule = [True] * args.cold + [False] * args.rounds
    for i, cold in enumerate(schedule):
        order = ("rdsl", "mitsuba") if i % 2 == 0 else ("mitsuba", "rdsl")
        for who in order:
            runs.append(spawn(who, args, cold))
            print(f"  {who} {'cold' if cold else 'warm'}: {runs[-1]['per_iter']:.3f} s/iter, "
                  f"first {runs[-1]['first']:.2f} s, {runs[-1]['rss_mib']:.0f} MiB",
                  flush=True)
    print()
    table(runs)
    if args.rounds:
        summary(runs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
