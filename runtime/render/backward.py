"""Reverse-mode gradients of a scene's image: ``scene.backward(d_img, params=[...])``.

``backward`` returns d loss / d parameter for every name in ``params`` at once, given
d loss / d image (``d_img``, shaped like ``render()``'s colour channels), by one adjoint
render: the generic kernel built with ``ad="reverse"`` (compiler/passes/ad_reverse.py).
Per batch of samples:

1. the plain generic kernel gives each sample's film weights, and so each pixel's total
   weight (the film divides by it: a pixel is sum w v / sum w);
2. each sample's adjoint is then sum over the pixels it reaches of w * d_img / total
   weight, computed here (it only moves numbers between the image and the samples);
3. the adjoint kernel recomputes the sample and sweeps it backwards, adding the gradient of
   ``PRM`` into a row of ``gPRM`` of its own per sample (``ad_row``): no two lanes or threads
   write one element, and the rows are summed at the end.

The estimate is that of the same Monte Carlo render (same seed and spp), as
``render_forward``'s: the dot product of ``backward``'s gradient with a tangent equals that
of ``render_forward``'s derivative image with ``d_img`` (tests/test_ad_reverse.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.build import elimination_threshold
from ...compiler.diagnostics import CompileError
from .differentiable import _lookup, ad_twin
from .film import film_reach, film_uniforms

if TYPE_CHECKING:
    from .renderer import Scene

__all__ = ["backward"]


def _check(scene: Scene, d_img: Any, params: list[str]) -> tuple[np.ndarray, dict]:
    """``d_img`` as float64 and the slots of ``params``, or a clear error."""
    if scene.build.model.spectral:
        raise CompileError("reverse-mode gradients in the spectral variants are not "
                           "supported yet (colours are stored as upsampling coefficients); "
                           "render in `rgb` or `mono`")
    if isinstance(params, str):
        params = [params]
    slots = scene.params.slots
    integrators = {i.name or i.plugin for i in scene.scene_spec_for_params().integrators}
    chosen = {}
    for name in params:
        key, slot = _lookup(slots, name)
        if key.split(".")[0] in integrators:
            raise CompileError(f"`{name}` is an integer setting of the integrator, which has "
                               "no derivative; differentiate a BSDF, texture or emitter "
                               "parameter")
        chosen[name] = slot
    film = film_uniforms(scene.desc.sensor.film, 1, channels=1)
    c = 1 if scene.build.model.mono else 3
    shape = (film["crop_h"], film["crop_w"], c)
    d = np.asarray(d_img, np.float64)
    if d.shape != shape and not (c == 1 and d.shape == shape[:2]):
        raise ValueError(f"d_img has shape {d.shape}; the image's colour channels are "
                         f"{shape}")
    return d.reshape(shape), chosen


def _taps(film: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per film cell, the crop-relative pixel index of each of the (2n+1)^2 pixels a
    sample of the cell reaches (cells, rows, columns), and whether it is in the crop."""
    cell = np.arange(film["grid_w"] * film["grid_h"])
    k = np.arange(2 * n + 1)
    qx = (cell % film["grid_w"] + film["grid_x"] - film["crop_x"])[:, None] - n + k
    qy = (cell // film["grid_w"] + film["grid_y"] - film["crop_y"])[:, None] - n + k
    h, w = film["crop_h"], film["crop_w"]
    ok = ((qy >= 0) & (qy < h))[:, :, None] & ((qx >= 0) & (qx < w))[:, None, :]
    pix = np.clip(qy, 0, h - 1)[:, :, None] * w + np.clip(qx, 0, w - 1)[:, None, :]
    return pix, ok


def _weights(out: dict, n: int, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """The samples' column and row filter weights, (samples per cell, cells, 2n+1) each
    (a batch is sample-major: sample j is in cell j % cells)."""
    m = 2 * n + 1
    wx = np.stack([np.asarray(out[f"w{k}"], np.float32) for k in range(m)], -1)
    wy = np.stack([np.asarray(out[f"w{m + k}"], np.float32) for k in range(m)], -1)
    return wx.reshape(-1, cells, m), wy.reshape(-1, cells, m)


# long: two passes over the batches, then the reduction
def backward(scene: Scene, d_img: Any, params: list[str], spp: int | None = None,
             seed: int | None = None, threads: int | None = None,
             eliminate: bool | int = False) -> dict[str, np.ndarray]:
    """d loss / d parameter for each name of ``params``, given d loss / d image."""
    from .renderer import BATCH_SAMPLES

    d, chosen = _check(scene, d_img, params)
    spp = int(spp or scene.spp)
    seed = scene.seed if seed is None else int(seed)
    scene.use_generic()
    plain = scene.compile()
    twin = ad_twin(scene, "reverse", elimination_threshold("reverse", eliminate))
    mod = twin.compile()
    for m in (plain, mod):
        if m.traces_rays:
            m.bind_scene(scene.embree)
    prm = np.array(scene.prm, np.float32)
    twin.prm = prm
    film = film_uniforms(scene.desc.sensor.film, 1, channels=1)
    n = film_reach(film)
    cells = film["grid_w"] * film["grid_h"]
    batch = max(1, min(spp, BATCH_SAMPLES // max(cells, 1)))
    seed_bits = int(np.uint32(seed).view(np.int32))
    batches = []
    for done in range(0, spp, batch):
        k = min(batch, spp - done)
        j = np.arange(cells * k, dtype=np.int32)
        rs = np.array([done, spp, seed_bits], np.int32)
        batches.append((j, rs))
    pix, ok = _taps(film, n)
    per_tap = np.zeros(pix.shape)
    outs = []
    for j, rs in batches:  # 1. the film's total weight per pixel
        out = plain["render_sample"](j, rs, *scene.buffers.args(), prm, threads=threads)
        wx, wy = _weights(out, n, cells)
        outs.append((wx, wy))
        per_tap += np.einsum("scr,scq->crq", wy, wx, dtype=np.float64)
    h, w = film["crop_h"], film["crop_w"]
    weights = np.bincount(pix[ok], per_tap[ok], h * w).reshape(h, w)
    g = d / np.where(weights == 0, 1.0, weights)[..., None]
    g_taps = np.where(ok[..., None], g.reshape(h * w, -1)[pix], 0.0)  # (cells, r, q, C)
    kernel = next(k for k in mod.manifest["kernels"] if k["name"] == "render_sample")
    names = [p["name"] for p in kernel["params"]]
    total = np.zeros(prm.size, np.float64)
    for (j, rs), (wx, wy) in zip(batches, outs):  # 2. and 3.
        a = np.einsum("scr,scq,crqx->scx", wy, wx, g_taps.astype(np.float32),
                      optimize=True).reshape(j.size, -1)
        seeds = {f"a_ret_value_{c}": a[:, i] for i, c in enumerate("xyz"[:a.shape[1]])}
        if a.shape[1] == 1:
            seeds = {"a_ret_value": a[:, 0]}
        args = []
        grad = np.zeros(j.size * prm.size, np.float32)
        for name in names[names.index("PRM") + 1:]:
            if name == "gPRM":
                args.append(grad)
            elif name == "ad_row":
                args.append(j * np.int32(prm.size))
            else:
                args.append(seeds.get(name, np.zeros(j.size, np.float32)))
        mod["render_sample"](j, rs, *scene.buffers.args(), prm, *args, threads=threads)
        total += grad.reshape(j.size, prm.size).sum(0, dtype=np.float64)
    return {name: total[s.offset:s.offset + s.size].astype(np.float32)
            for name, s in chosen.items()}
