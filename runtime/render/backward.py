"""Reverse-mode gradients of a scene's image: ``scene.backward(d_img, params=[...])``.

``backward`` returns d loss / d parameter for every name in ``params`` at once, given
d loss / d image (``d_img``, shaped like ``render()``'s colour channels), by one adjoint
render: the generic kernel built with ``ad="reverse"`` (compiler/passes/ad_reverse.py).
Per batch of samples:

1. the plain generic kernel gives each sample's film weights, and so each pixel's total
   weight (the film divides by it: a pixel is sum w v / sum w), or those the last
   ``render()`` of the same samples kept (in the generic build);
2. each sample's adjoint is then sum over the pixels it reaches of w * d_img / total
   weight, computed here (it only moves numbers between the image and the samples);
3. the adjoint kernel recomputes the sample and sweeps it backwards, adding the gradient of
   ``PRM`` into a row of ``gPRM`` (``ad_row``) and that of the texels ``T`` into a row of
   ``gT`` (``ad_row_T``) of the sample's lane (:class:`_Parts`): no two lanes running at
   once write one element, and the rows are summed at the end.

The estimate is that of the same Monte Carlo render (same seed and spp), as
``render_forward``'s: the dot product of ``backward``'s gradient with a tangent equals that
of ``render_forward``'s derivative image with ``d_img`` (tests/test_ad_reverse.py).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.build import elimination_threshold
from ...compiler.diagnostics import CompileError
from ...core.scene_spec import Slot
from .differentiable import Texels, _lookup, ad_twin
from .film import film_reach, film_uniforms, sample_weights

if TYPE_CHECKING:
    from .renderer import Scene

__all__ = ["backward"]


def _check(scene: Scene, d_img: Any, params: list[str]) -> tuple[np.ndarray, dict]:
    """``d_img`` as float64 and the slots of ``params``, or a clear error."""
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


LANES = 16  # the widest SIMD packet: lanes of one packet add gradients into rows of their
# own (array position mod LANES), each part of the adjoint pass into LANES rows (_Parts)
PARTS_PER_THREAD = 4
CELLS_AT_ONCE = 2048
TAPE = 16  # bounces whose carried state the adjoint kernel checkpoints per lane (the
# rest it recomputes from the last checkpoint: compiler/passes/ad_reverse.py)


# long: two passes over the batches, then the reduction
def backward(scene: Scene, d_img: Any, params: list[str], spp: int | None = None,
             seed: int | None = None, threads: int | None = None,
             eliminate: bool | int = False, tape: int = TAPE) -> dict[str, np.ndarray]:
    """d loss / d parameter for each name of ``params``, given d loss / d image (``tape``:
    bounces checkpointed per lane, 0 to recompute each bounce's state from the start)."""
    from .renderer import BATCH_SAMPLES

    d, chosen = _check(scene, d_img, params)
    spp = int(spp or scene.spp)
    seed = scene.seed if seed is None else int(seed)
    scene.use_generic()
    plain = scene.compile()
    twin = ad_twin(scene, "reverse", elimination_threshold("reverse", eliminate), tape)
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
    # the film weights of the samples: those the last render() of these samples kept (they
    # depend on where each sample falls on the film, not on the parameters), or a plain pass
    kept = getattr(scene, "film_weights", None)
    kept = kept[1] if kept and kept[0] == (spp, seed) and kept[1] is not None and \
        len(kept[1]) == len(batches) else None
    scene.film_weights = None  # used once: its memory is free again
    for b, (j, rs) in enumerate(batches):  # 1. the film's total weight per pixel
        if kept is not None:
            wx, wy = kept[b]
        else:
            out = plain["render_sample"](j, rs, *scene.buffers.args(), prm, threads=threads)
            wx, wy = sample_weights(out, n, cells)
        outs.append((wx, wy))
        # sum over the samples of wy wx^T, per cell: a batched matrix product
        per_tap += np.matmul(wy.transpose(1, 2, 0), wx.transpose(1, 0, 2))
    h, w = film["crop_h"], film["crop_w"]
    weights = np.bincount(pix[ok], per_tap[ok], h * w).reshape(h, w)
    g = d / np.where(weights == 0, 1.0, weights)[..., None]
    # per cell, the taps' g as (columns, rows x channels), 0 outside the crop
    g_qrx = g.astype(np.float32).reshape(h * w, -1)[pix.transpose(0, 2, 1)]
    g_qrx *= ok.transpose(0, 2, 1)[..., None]
    g_qrx = g_qrx.reshape(len(pix), pix.shape[2], -1)
    kernel = next(k for k in mod.manifest["kernels"] if k["name"] == "render_sample")
    names = [p["name"] for p in kernel["params"]]
    parts = _Parts(prm, scene.buffers.T, any(isinstance(c, Texels) for c in chosen.values()),
                   threads)
    floats = next((p.get("tape_floats", 0) for p in kernel["params"]
                   if p["name"] == "ad_tape"), 0)
    tape_rows = np.zeros(max(1, parts.parts * LANES * floats), np.float32)  # per lane
    uniform = {"gPRM": parts.gPRM, "gT": parts.gT, "ad_tape": tape_rows}
    for (j, rs), (wx, wy) in zip(batches, outs):  # 2. and 3.
        a = _sample_adjoints(wx, wy, g_qrx)
        seeds = {f"a_ret_value_{c}": a[:, i] for i, c in enumerate("xyz"[:a.shape[1]])}
        if a.shape[1] == 1:
            seeds = {"a_ret_value": a[:, 0]}
        varying = {"ad_row": parts.rows(j.size, prm.size), "ad_row_T":
                   parts.rows(j.size, scene.buffers.T.size) if parts.texels else
                   np.zeros(j.size, np.int32), "ad_row_tape": parts.rows(j.size, floats)} | seeds
        head = [rs, *scene.buffers.args(), prm]
        zero = np.zeros(j.size, np.float32)  # every adjoint seed that is 0 (read only)
        rest = [(uniform[x], False) if x in uniform else (varying.get(x, zero), True)
                for x in names[names.index("PRM") + 1:]]
        parts.run(partial(_adjoint_part, mod["render_sample"], j, head, rest), j.size)
    return {name: parts.gradient(c) for name, c in chosen.items()}


def _sample_adjoints(wx: np.ndarray, wy: np.ndarray, g_qrx: np.ndarray) -> np.ndarray:
    """Each sample's adjoint, sum over the pixels it reaches of wy wx g (g: d_img over the
    pixel's total weight, per cell as (columns, rows x channels)): (samples, channels).
    Batched matrix products (numpy's einsum of the three took 3x as long)."""
    s, cells, m = wx.shape
    out = np.empty((s, cells, g_qrx.shape[2] // m), np.float32)
    for lo in range(0, cells, CELLS_AT_ONCE):  # a few MB of temporaries at a time
        hi = min(lo + CELLS_AT_ONCE, cells)
        t = np.matmul(wx[:, lo:hi].transpose(1, 0, 2), g_qrx[lo:hi])  # (cells, s, m x C)
        t = t.reshape(hi - lo, s, m, -1) * wy[:, lo:hi].transpose(1, 0, 2)[..., None]
        out[:, lo:hi] = t.sum(2).transpose(1, 0, 2)
    return out.reshape(s * cells, -1)


def _adjoint_part(kernel, j: np.ndarray, head: list, rest: list, lo: int, hi: int) -> None:
    """The adjoint kernel over samples [lo, hi) of a batch (``rest``: the adjoint's own
    arguments and whether each is varying: those are sliced, the gradient buffers not)."""
    kernel(j[lo:hi], *head, *[x[lo:hi] if varying else x for x, varying in rest], threads=1)


class _Parts:
    """The adjoint pass split into parts of whole packets, ``PARTS_PER_THREAD`` per thread
    (so a slow thread holds up little), each with ``LANES`` rows of its own in each gradient
    buffer: lane k of a packet adds into row k of its part, so no two lanes running at once
    add into one element (no atomics), and the buffers stay small (parts x LANES rows, not
    one per sample).  Without texel parameters ``gT`` is one row nobody reads (the adjoint
    kernel writes it anyway)."""

    def __init__(self, prm: np.ndarray, T: np.ndarray, texels: bool,
                 threads: int | None) -> None:
        self.threads = max(1, int(threads or os.cpu_count() or 1))
        self.parts = 1 if self.threads == 1 else self.threads * PARTS_PER_THREAD
        rows = self.parts * LANES
        if rows * max(T.size if texels else 0, prm.size) >= 2 ** 31:
            raise ValueError(f"texel gradients of {T.size} floats in {rows} rows exceed "
                             "32-bit indices; use fewer threads")
        self.texels = texels
        self.gPRM = np.zeros(rows * prm.size, np.float32)
        self.gT = np.zeros(rows * T.size if texels else T.size, np.float32)

    def _bounds(self, n: int) -> list[tuple[int, int]]:
        per = -(-n // self.parts)  # ceil: parts of whole packets
        step = -(-per // LANES) * LANES
        return [(lo, min(lo + step, n)) for lo in range(0, n, step)]

    def rows(self, n: int, size: int) -> np.ndarray:
        """The first element of each sample's row, in a buffer of rows of ``size``."""
        rows = np.empty(n, np.int32)
        for p, (lo, hi) in enumerate(self._bounds(n)):
            rows[lo:hi] = (p * LANES + np.arange(hi - lo) % LANES) * size
        return rows

    def run(self, call, n: int) -> None:
        """``call(lo, hi)`` over the parts of [0, n), on ``threads`` threads."""
        if self.parts == 1:
            call(0, n)
            return
        with ThreadPoolExecutor(self.threads) as pool:
            for f in [pool.submit(call, lo, hi) for lo, hi in self._bounds(n)]:
                f.result()

    def gradient(self, chosen: Slot | Texels) -> np.ndarray:
        if isinstance(chosen, Texels):
            total = self.gT.reshape(self.parts * LANES, -1).sum(0, dtype=np.float64)
            g = sum(total[off:off + chosen.size] / scale for off, scale in chosen.copies)
            return np.asarray(g, np.float32).reshape(chosen.shape)
        total = self.gPRM.reshape(self.parts * LANES, -1).sum(0, dtype=np.float64)
        return total[chosen.offset:chosen.offset + chosen.size].astype(np.float32)
