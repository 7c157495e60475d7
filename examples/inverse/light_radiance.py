"""Recover the radiance of the Cornell box's area light from a target image.

    python examples/inverse/light_radiance.py [--iterations 80] [--res 48] [--spp 16]

The target is the Cornell box with its true light (radiance 18.4, 14.0, 6.75), rendered at
8x the spp; the light starts a dim grey (5, 5, 5) and Adam (rdsl.optim) descends the
relative squared error of the image with reverse-mode gradients (``scene.backward``: one
adjoint render for the three components; docs/ad.md).  Prints the loss and the radiance per
iteration and the error of the recovered radiance against the truth; writes
out/inverse/radiance_{before,target,after}.png and the loss curve radiance_loss.png.
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
LIGHT = "light.emitter.radiance"
# the adjoint renders with other samples than the image the loss compares: the gradient of
# a squared error from one set of samples is biased (E[(X - t) dX] != (E[X] - t) E[dX])
DECORRELATE = 1 << 20


def recover(res: int = 48, spp: int = 16, iterations: int = 80, lr: float = 1.0,
            max_depth: int = 4, start: float = 5.0, out: Path | None = None, log=print,
            decay: float = 0.97) -> dict[str, np.ndarray]:
    """Run the optimization; returns the recovered radiance, the truth and the losses."""
    scene = rdsl.load_scene(SCENE, res=res, spp=spp, max_depth=max_depth)
    truth = scene.params[LIGHT]
    target = scene.render(spp=8 * spp, seed=1000)
    got, losses, before = descend(
        scene, {LIGHT: np.full(3, start, np.float32)}, target, iterations, lr,
        lambda names, d_img, it: scene.backward(d_img, names, seed=DECORRELATE + it),
        bounds=(0.0, 100.0), decay=decay, log=log)
    err = np.abs(got[LIGHT] - truth) / truth
    log(f"{LIGHT}: recovered {np.round(got[LIGHT], 3)}, truth {np.round(truth, 3)}, "
        f"relative error {np.round(err, 4)}")
    if out is not None:
        save(out, "radiance", {"before": before, "target": target, "after": scene.render()},
             losses, "Cornell box light radiance, reverse-mode gradients", log)
    return {LIGHT: got[LIGHT], "truth": truth, "losses": np.array(losses)}


def main() -> None:
    args = arguments(__doc__, iterations=80, res=48, spp=16, lr=1.0)
    recover(args.res, args.spp, args.iterations, args.lr, out=Path(args.out))


if __name__ == "__main__":
    main()
