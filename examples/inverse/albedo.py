"""Recover the Cornell box's red and green wall albedos from a target image.

    python examples/inverse/albedo.py [--iterations 80] [--res 48] [--spp 32]

The target is the Cornell box with its true albedos, rendered at 8x the spp; the walls start
grey (0.5) and Adam (rdsl.optim) descends the mean squared error of the image, with the
gradient of the relative squared error from forward-mode AD (scene.gradient: one derivative render per colour component;
docs/ad.md).  Prints the loss and the albedos per iteration and the error of the recovered
values against the truth; writes out/inverse/albedo_{before,target,after}.png and, with
matplotlib, the loss curve albedo_loss.png.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import rdsl
from rdsl.runtime.render.image import write_png

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT.parent / "shared" / "scenes" / "cbox" / "cbox.xml"
WALLS = ("red.reflectance", "green.reflectance")


def recover(res: int = 48, spp: int = 32, iterations: int = 80, lr: float = 0.03,
            max_depth: int = 4, out: Path | None = None, log=print,
            decay: float = 0.98) -> dict[str, np.ndarray]:
    """Run the optimization; returns the recovered albedos by name (and logs the truth)."""
    scene = rdsl.load_scene(SCENE, res=res, spp=spp, max_depth=max_depth)
    truth = {k: scene.params[k] for k in WALLS}
    target = scene.render(spp=8 * spp, seed=1000)
    opt = rdsl.optim.Adam(lr=lr)
    for k in WALLS:
        opt[k] = np.full(3, 0.5, np.float32)
    losses = []
    before = None
    tail = {k: [] for k in WALLS}  # the last iterates, averaged at the end (Polyak)
    t0 = time.perf_counter()
    for it in range(iterations):
        for k in WALLS:
            scene.params[k] = opt[k]
        img = scene.render(seed=it)
        before = img if before is None else before
        # relative squared error, so that the dark channels (a red wall's green) count too
        weight = 1.0 / (target.astype(np.float64) + 0.05) ** 2
        diff = img.astype(np.float64) - target
        losses.append(float(np.mean(weight * diff * diff)))
        grads = scene.gradient(list(WALLS), 2.0 * weight * diff / diff.size, seed=it)
        opt.step(grads)
        for k in WALLS:
            opt.clamp(k, 0.0, 1.0)
        opt.lr *= decay  # smaller steps as the noise of the gradient starts to dominate
        for k in WALLS:
            if it >= iterations - max(iterations // 4, 1):
                tail[k].append(opt[k].copy())
        log(f"iteration {it:3d}  loss {losses[-1]:.3e}  "
            + "  ".join(f"{k.split('.')[0]} {np.round(opt[k], 3)}" for k in WALLS))
    log(f"{iterations} iterations in {time.perf_counter() - t0:.1f} s")
    for k in WALLS:  # the mean of the last quarter of the iterates: less noise
        opt[k] = np.mean(tail[k], axis=0)
        scene.params[k] = opt[k]
    for k in WALLS:
        err = np.abs(opt[k] - truth[k]) / truth[k]
        log(f"{k}: recovered {np.round(opt[k], 4)}, truth {np.round(truth[k], 4)}, "
            f"relative error {np.round(err, 4)}")
    if out is not None:
        _save(out, scene, before, target, losses)
    return {k: opt[k] for k in WALLS} | {f"truth.{k}": truth[k] for k in WALLS}


def _save(out: Path, scene, before, target, losses) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, img in (("before", before), ("target", target), ("after", scene.render())):
        write_png(out / f"albedo_{name}.png", img)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed (pip install -e '.[bench]'): no loss curve")
        return
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.semilogy(losses)
    ax.set_xlabel("iteration")
    ax.set_ylabel("relative squared error")
    ax.set_title("Cornell box wall albedos, forward-mode gradients")
    fig.tight_layout()
    fig.savefig(out / "albedo_loss.png", dpi=120)
    print(f"wrote {out}/albedo_*.png")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=80)
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--lr", type=float, default=0.03)
    ap.add_argument("--out", default=str(ROOT / "out" / "inverse"))
    args = ap.parse_args()
    if not SCENE.is_file():
        raise SystemExit(f"{SCENE}: the shared scenes are not next to this checkout")
    recover(args.res, args.spp, args.iterations, args.lr, out=Path(args.out))


if __name__ == "__main__":
    main()
