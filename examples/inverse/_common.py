"""What the inverse-rendering examples share: the descent loop and the pictures.

``descend`` runs Adam (rdsl.optim) on named scene parameters against a target image with a
relative squared error (each pixel's squared difference over (target + 0.05)^2, so dark
channels count too) and returns the mean of the last quarter of the iterates (Polyak
averaging: less Monte Carlo noise than the last iterate).  ``save`` writes the
before/target/after images and the loss curve.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import rdsl
from rdsl.runtime.render.image import write_png


def loss_and_grad(img: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray]:
    """The relative squared error of ``img`` against ``target`` and its gradient with
    respect to the image."""
    weight = 1.0 / (target.astype(np.float64) + 0.05) ** 2
    diff = img.astype(np.float64) - target
    return float(np.mean(weight * diff * diff)), 2.0 * weight * diff / diff.size


# long: the descent loop, its logging and the averaging of the tail
def descend(scene, start: dict[str, np.ndarray], target: np.ndarray, iterations: int,
            lr: float, gradient: Callable, bounds: tuple[float, float] = (0.0, 1.0),
            decay: float = 0.98, log=print, show: Callable | None = None
            ) -> tuple[dict[str, np.ndarray], list[float], np.ndarray]:
    """Adam from ``start`` (name -> value) for ``iterations`` steps; ``gradient(names,
    d_img, seed)`` gives d loss / d parameter.  Returns the averaged tail of the iterates,
    the losses and the first image."""
    opt = rdsl.optim.Adam(lr=lr)
    for k, v in start.items():
        opt[k] = v
    losses: list[float] = []
    before = None
    tail: dict[str, list[np.ndarray]] = {k: [] for k in start}
    show = show or (lambda k, v: np.round(v, 3))
    t0 = time.perf_counter()
    for it in range(iterations):
        for k in start:
            scene.params[k] = opt[k]
        img = scene.render(seed=it)
        before = img if before is None else before
        loss, d_img = loss_and_grad(img, target)
        losses.append(loss)
        opt.step(gradient(list(start), d_img, it))
        for k in start:
            opt.clamp(k, *bounds)
        opt.lr *= decay  # smaller steps as the noise of the gradient starts to dominate
        if it >= iterations - max(iterations // 4, 1):
            for k in start:
                tail[k].append(opt[k].copy())
        log(f"iteration {it:3d}  loss {loss:.3e}  "
            + "  ".join(f"{k.split('.')[0]} {show(k, opt[k])}" for k in start))
    log(f"{iterations} iterations in {time.perf_counter() - t0:.1f} s")
    out = {k: np.mean(tail[k], axis=0).astype(np.float32) for k in start}
    for k, v in out.items():
        scene.params[k] = v
    return out, losses, before


def save(out: Path, prefix: str, images: dict[str, np.ndarray], losses: list[float],
         title: str, log=print) -> None:
    """``{prefix}_{name}.png`` for each image and the loss curve ``{prefix}_loss.png``."""
    out.mkdir(parents=True, exist_ok=True)
    for name, img in images.items():
        write_png(out / f"{prefix}_{name}.png", img)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("matplotlib is not installed (pip install -e '.[bench]'): no loss curve")
        return
    fig, ax = plt.subplots(figsize=(5, 3.5))
    ax.semilogy(losses)
    ax.set_xlabel("iteration")
    ax.set_ylabel("relative squared error")
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(out / f"{prefix}_loss.png", dpi=120)
    plt.close(fig)
    log(f"wrote {out}/{prefix}_*.png")


def arguments(doc: str, **defaults: float) -> argparse.Namespace:
    """The command line of an example: ``--NAME`` for each default (its type from the
    default's), and ``--out`` (out/inverse)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    for name, value in defaults.items():
        ap.add_argument(f"--{name}", type=type(value), default=value)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[2] / "out" /
                                         "inverse"))
    return ap.parse_args()
