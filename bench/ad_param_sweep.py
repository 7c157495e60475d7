"""Forward against reverse mode on every parameter of a set of scenes: for each scene
(bench/scenes/set/ by default), ``backward`` of a random linear loss for all its float
parameters at once, then ``render_forward`` along a random tangent for each, both with
one seed; prints per scene the worst relative difference of the two directional
derivatives, the parameters whose derivative is zero in both, and any NaN.

    python bench/ad_param_sweep.py [SCENE.xml ...] [--spp 2]

Integrator settings and integer choices (a microfacet distribution) have no derivative and
are left out.  A derivative that is zero in exact arithmetic (a smooth dielectric's IOR,
whose delta lobe's weight F / F does not depend on it) shows as rounding noise, where the
two modes differ in relative terms.  Not a test: run it by hand (docs/ad.md)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SET = ROOT / "bench" / "scenes" / "set"
NO_DERIVATIVE = {"distribution", "nonlinear", "sample_visible", "emitter_samples",
                 "bsdf_samples", "hide_emitters", "max_depth", "rr_depth"}


def sweep(path: Path, spp: int) -> str:
    import rdsl

    scene = rdsl.load_scene(path)
    names = [k for k in scene.params.keys() if not k.endswith(".data")
             and k.rsplit(".", 1)[-1] not in NO_DERIVATIVE and scene.params[k].size <= 4]
    w = np.random.default_rng(0).random(scene.render(spp=spp, seed=1).shape)
    grads = scene.backward(w, names, spp=spp, seed=5)
    worst, zero, bad = 0.0, [], []
    for name in names:
        t = np.random.default_rng(1).uniform(0.5, 1, grads[name].size).astype(np.float32)
        _, d_img = scene.render_forward(name, spp=spp, seed=5, tangent=t)
        fwd = float((d_img.astype(np.float64) * w).sum())
        rev = float(np.dot(grads[name].astype(np.float64), t))
        if not (np.isfinite(fwd) and np.isfinite(rev)):
            bad.append(name)
        elif abs(fwd) < 1e-9 and abs(rev) < 1e-9:
            zero.append(name)
        else:
            worst = max(worst, abs(rev - fwd) / max(abs(fwd), 1e-6))
    return (f"{len(names):3d} params, worst relative difference {worst:.1e}; "
            f"NaN: {bad or 'none'}; zero: {', '.join(zero) or 'none'}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", type=Path)
    ap.add_argument("--spp", type=int, default=2)
    args = ap.parse_args()
    if not args.scenes:
        sys.path.insert(0, str(ROOT / "bench" / "scenes"))
        import make_set

        make_set.generate()
    for path in args.scenes or sorted(SET.glob("*.xml")):
        t = time.perf_counter()
        print(f"{path.stem:28s} {sweep(path, args.spp)} ({time.perf_counter() - t:.0f} s)",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
