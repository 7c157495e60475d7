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

import sys
from pathlib import Path

import numpy as np
import rdsl

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import arguments, descend, save  # examples/inverse/_common.py

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "examples" / "cbox" / "cbox.xml"
WALLS = ("red.reflectance", "green.reflectance")


def recover(res: int = 48, spp: int = 32, iterations: int = 80, lr: float = 0.03,
            max_depth: int = 4, out: Path | None = None, log=print,
            decay: float = 0.98) -> dict[str, np.ndarray]:
    """Run the optimization; returns the recovered albedos by name (and logs the truth)."""
    scene = rdsl.load_scene(SCENE, res=res, spp=spp, max_depth=max_depth)
    truth = {k: scene.params[k] for k in WALLS}
    target = scene.render(spp=8 * spp, seed=1000)
    start = {k: np.full(3, 0.5, np.float32) for k in WALLS}
    got, losses, before = descend(
        scene, start, target, iterations, lr,
        lambda names, d_img, it: scene.gradient(names, d_img, seed=it), decay=decay, log=log)
    for k in WALLS:
        err = np.abs(got[k] - truth[k]) / truth[k]
        log(f"{k}: recovered {np.round(got[k], 4)}, truth {np.round(truth[k], 4)}, "
            f"relative error {np.round(err, 4)}")
    if out is not None:
        save(out, "albedo", {"before": before, "target": target, "after": scene.render()},
             losses, "Cornell box wall albedos, forward-mode gradients", log)
    return got | {f"truth.{k}": truth[k] for k in WALLS}


def main() -> None:
    args = arguments(__doc__, iterations=80, res=48, spp=32, lr=0.03)
    recover(args.res, args.spp, args.iterations, args.lr, out=Path(args.out))


if __name__ == "__main__":
    main()
