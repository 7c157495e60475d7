"""Recover a 64x64 bitmap texture on the Cornell box's back wall from a target image.

    python examples/inverse/texture.py [--iterations 80] [--res 128] [--spp 4]

The back wall gets a diffuse BSDF whose reflectance is a bitmap texture with id
`wall_texture` (a checkerboard with a soft green spot, made here and written as an EXR).  The
target is that scene rendered at 512 spp; the texture starts a flat grey (0.5) and Adam
(rdsl.optim) descends the relative squared error of the image with reverse-mode gradients
of its texels (``scene.params["wall_texture.data"]``, Mitsuba's ``<id>.data``; each texel
read becomes an addition into a gradient buffer: docs/ad.md).  Prints the loss per iteration
and the error of the recovered texels against the truth (where the camera sees the wall);
writes out/inverse/texture_{before,target,after}.png, the recovered and true textures
(texture_recovered.png, texture_truth.png) and the loss curve texture_loss.png.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import rdsl
from rdsl.runtime.render.image import write_exr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import arguments, descend, save  # examples/inverse/_common.py

ROOT = Path(__file__).resolve().parents[2]
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
TEXELS = "wall_texture.data"
WALL = """<bsdf type="diffuse" id="backwall">
        <texture type="bitmap" name="reflectance" id="wall_texture">
            <string name="filename" value="wall.exr"/>
        </texture>
    </bsdf>
    """


def truth_texture(n: int = 64) -> np.ndarray:
    """A 4x4 checkerboard (0.2 / 0.8 in red), a soft green spot, a blue ramp."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    checker = ((x * 4).astype(int) + (y * 4).astype(int)) % 2
    return np.stack([0.2 + 0.6 * checker,
                     0.25 + 0.5 * np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2) / 0.04),
                     0.2 + 0.5 * x], -1).astype(np.float32)


def textured_cbox(folder: Path, n: int = 64) -> Path:
    """The Cornell box with the textured back wall, written into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    write_exr(folder / "wall.exr", truth_texture(n))
    xml = CBOX.read_text()
    back = r'(<shape type="rectangle" id="back">\s*<transform name="to_world">\s*' \
           r'<translate z="-1"/>\s*</transform>\s*)<ref id="white"/>'
    xml, found = re.subn(back, r'\1<ref id="backwall"/>', xml)
    assert found == 1, "the back wall of examples/cbox/cbox.xml changed"
    xml = xml.replace('<shape type="rectangle" id="back">',
                      WALL + '<shape type="rectangle" id="back">')
    (folder / "cbox_textured.xml").write_text(xml)
    return folder / "cbox_textured.xml"


def seen(scene, res: int) -> np.ndarray:
    """Which texels the camera sees directly, (H, W): those whose gradient of the image's
    sum is at least a fifth of the median nonzero one (a texel seen only in reflections or
    behind the light's edge has a far smaller one)."""
    g = np.abs(scene.backward(np.ones((res, res, 3)), [TEXELS], spp=16, seed=7)[TEXELS])
    g = g.sum(-1)
    return g >= 0.2 * np.median(g[g > 0])


# long: the set-up, the descent and the report
def recover(res: int = 128, spp: int = 4, iterations: int = 80, lr: float = 0.05,
            max_depth: int = 3, target_spp: int = 512, folder: Path | None = None,
            out: Path | None = None, log=print, decay: float = 0.97) -> dict[str, np.ndarray]:
    """Run the optimization; returns the recovered texels, the truth, the texels the camera
    sees and the losses."""
    folder = folder or ROOT / "out" / "inverse"
    scene = rdsl.load_scene(textured_cbox(folder), res=res, spp=spp, max_depth=max_depth)
    truth = scene.params[TEXELS]
    # a clean target: each texel is seen by a few pixels only, whose noise it would fit
    target = scene.render(spp=target_spp, seed=1000)
    mask = seen(scene, res)
    start = np.full(truth.shape, 0.5, np.float32)
    got, losses, before = descend(
        scene, {TEXELS: start}, target, iterations, lr,
        lambda names, d_img, it: scene.backward(d_img, names, seed=(1 << 20) + it),
        decay=decay, log=log, show=lambda k, v: f"mean {v.mean():.3f}")
    texels = got[TEXELS].reshape(truth.shape)
    err0 = np.abs(start - truth)[mask].mean()
    err = np.abs(texels - truth)[mask].mean()
    log(f"{TEXELS}: mean absolute error of the {mask.sum()} texels the camera sees "
        f"{err:.4f} (the grey start's: {err0:.4f})")
    if out is not None:
        save(out, "texture", {"before": before, "target": target, "after": scene.render(),
                              "recovered": texels, "truth": truth}, losses,
             "Back-wall texture (64x64), reverse-mode gradients", log)
    return {TEXELS: texels, "truth": truth, "seen": mask, "losses": np.array(losses),
            "start": start}


def main() -> None:
    args = arguments(__doc__, iterations=80, res=128, spp=4, lr=0.05)
    recover(args.res, args.spp, args.iterations, args.lr, out=Path(args.out))


if __name__ == "__main__":
    main()
