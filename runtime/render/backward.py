"""Reverse-mode gradients of a scene's image: ``scene.backward(d_img, params=[...])``.

``backward`` returns d loss / d parameter for every name in ``params`` at once, given
d loss / d image (``d_img``, shaped like ``render()``'s colour channels), by one adjoint
render: the generic kernel built with ``ad="reverse"`` (compiler/passes/ad_reverse.py).
Per batch of samples:

1. each pixel's total film weight (the film divides by it: a pixel is sum w v / sum w):
   that the last ``render()`` of the same samples kept (in the generic build), or else
   the sum of the samples' weights from their positions alone, by two small kernels of the
   adjoint module (no path traced);
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
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.build import elimination_threshold
from ...compiler.diagnostics import CompileError
from ...compiler.passes.ad_checkpoint import OVERFLOW, TAPE_LANES
from ...core.scene_spec import Slot
from ..scene.samplers import requested_samples, sample_count
from .differentiable import Texels, _lookup, ad_twin, adjoint_seeds, integrator_names
from .film import film_reach, film_uniforms, gather_in_groups
from .kernel_source import SCENE_BUFFERS, batch_row

if TYPE_CHECKING:
    from .renderer import Scene

__all__ = ["backward"]

CPU_BACKENDS = ("llvm", "c")  # whose kernel calls run their elements in order, one thread
# per call (the adjoint pass gives each call's lanes gradient rows of their own)


def _check(scene: Scene, d_img: Any, params: list[str]) -> tuple[np.ndarray, dict]:
    """``d_img`` as float64 and the slots of ``params``, or a clear error."""
    if isinstance(params, str):
        params = [params]
    target = scene.build.target
    if target.backend not in CPU_BACKENDS:
        raise CompileError(f"scene.backward runs on the CPU targets (host, avx512, avx2, sse4, "
                           f"scalar, c), not on `{target.name}`: its work-items run at once "
                           "and would add into the same gradient rows; load the scene with "
                           "target='host' for gradients")
    slots = scene.params.slots
    integrators = set(integrator_names(scene))
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


LANES = TAPE_LANES  # the widest SIMD packet: lanes of one packet add gradients into rows of
# their own (array position mod LANES), each part of the adjoint pass into LANES rows (_Parts)
GUIDED = 2  # a part of the adjoint pass is 1 / (GUIDED x threads) of what is left, so
# the last parts are short (with 4 equal parts per thread, a 128 x 128 pass at 16 spp ended
# on one core for 11 ms of its 100)
MIN_PART = 512  # samples (0.4 ms here)
PARTS_PER_THREAD_TEXELS = 4  # with texel gradients, whose rows are a texture's size each
BATCH = 1 << 20  # samples per batch of the adjoint pass (24 bytes each, the arrays of one
# batch's rows and indices; a batch ends with a barrier, waiting for its last part)
WEIGHT_BATCH = 1 << 18  # samples per batch of the film-weight kernels (10 floats each
# with a gaussian filter: 10 MB; with 1 << 16, a 128 x 128 pass at 16 spp made 8 calls of
# tasks so short that one core ran most of them while the other woke)
TAPE = 16  # bounces whose carried state the adjoint kernel checkpoints per lane (the
# rest it recomputes from the last checkpoint: compiler/passes/ad_reverse.py)


def _pixel_adjoints(scene: Scene, mod: Any, d: np.ndarray, spp: int, seed: int,
                    threads: int | None) -> np.ndarray:
    """``D`` of ``render_sample_loss``: d loss / d pixel over the pixel's total film weight
    (that of the last ``render()`` of the same samples, or the film-weight kernels' of
    ``mod``, the adjoint module: :func:`_film_weights`), over the sample grid grown by the
    film's reach on each side, zero outside the crop, one plane per colour channel."""
    kept = getattr(scene, "film_weights", None)
    if not kept or kept[0] != (spp, seed):
        kept = scene.film_weights = ((spp, seed), _film_weights(scene, mod, spp, seed, threads))
    film = film_uniforms(scene.desc.sensor.film, 1, channels=1)
    h, w, n = film["crop_h"], film["crop_w"], film_reach(film)
    weights = kept[1].reshape(h, w, 1).astype(np.float64)
    pad = np.zeros((d.shape[2], film["grid_h"] + 2 * n, film["grid_w"] + 2 * n), np.float32)
    y, x = film["crop_y"] - film["grid_y"] + n, film["crop_x"] - film["grid_x"] + n
    pad[:, y:y + h, x:x + w] = np.moveaxis(d / np.where(weights == 0, 1.0, weights), 2, 0)
    return pad.reshape(-1)  # a plane per channel (kernel_source.py's _adjoint_source)


def _film_weights(scene: Scene, mod: Any, spp: int, seed: int,
                  threads: int | None) -> np.ndarray:
    """Each pixel's total film weight over the samples of ``spp`` and ``seed``, as a render
    sums it, from the samples' positions alone (``film_weight_sample`` and
    ``film_weight_pass``, stdlib/render/adjoint.rdsl.in): no path is traced.  A render
    leaves out the weights of samples whose radiance is NaN or infinite; this cannot."""
    film = film_uniforms(scene.desc.sensor.film, 1, channels=0)
    cells = film["grid_w"] * film["grid_h"]
    batch = max(1, min(spp, WEIGHT_BATCH // max(cells, 1)))
    planes = 2 * (2 * film_reach(film) + 1)
    acc = np.zeros(film["crop_w"] * film["crop_h"], np.float32)
    pixels = np.arange(acc.size, dtype=np.int32)
    j = np.arange(cells * batch, dtype=np.int32)
    block = np.empty(planes * j.size, np.float32)
    for done in range(0, spp, batch):
        m = min(batch, spp - done)
        ns = cells * m
        S = block[:planes * ns]
        mod["film_weight_sample"](j[:ns], batch_row(done, spp, seed, ns), S, threads=threads)
        gather_in_groups(mod["film_weight_pass"], pixels, m, ns, S, acc, threads)
    return acc


# long: the setup of the adjoint pass, then its batches
def backward(scene: Scene, d_img: Any, params: list[str], spp: int | None = None,
             seed: int | None = None, threads: int | None = None,
             eliminate: bool | int = False, tape: int = TAPE) -> dict[str, np.ndarray]:
    """d loss / d parameter for each name of ``params``, given d loss / d image (``tape``:
    bounces checkpointed per lane, 0 to recompute each bounce's state from the start)."""
    d, chosen = _check(scene, d_img, params)
    spp, seed = requested_samples(spp, seed, scene.spp, scene.seed)
    spp = sample_count(scene.desc.sensor.sampler, spp)
    scene.use_generic()
    covers = tape_covers(scene, tape)
    twin = ad_twin(scene, "reverse", elimination_threshold("reverse", eliminate), tape,
                   adjoint_seeds(chosen), covers)
    # as a render: the quick tier for a small pass not cached yet, the full one built in
    # the background from the second such pass and used once ready (renderer.py's _tiered)
    mod = twin._tiered(twin.compile(quick=twin.quick_fits(spp)))
    if mod.traces_rays:
        mod.bind_scene(scene.embree)
    D = _pixel_adjoints(scene, mod, d, spp, seed, threads)
    prm = twin.prm = twin.with_tables(np.array(scene.prm, np.float32), mod)
    film = film_uniforms(scene.desc.sensor.film, 1, channels=1)
    cells = film["grid_w"] * film["grid_h"]
    batch = max(1, min(spp, BATCH // max(cells, 1)))
    kernel = next(k for k in mod.manifest["kernels"] if k["name"] == "render_sample_loss")
    names = [p["name"] for p in kernel["params"]]
    sizes = sorted({cells * min(batch, spp - done) for done in range(0, spp, batch)})
    parts = _Parts(prm, scene.buffers.T, any(isinstance(c, Texels) for c in chosen.values()),
                   threads, sizes)
    floats = next((p.get("tape_floats", 0) for p in kernel["params"]
                   if p["name"] == "ad_tape"), 0)
    tape_rows = np.zeros(max(1, parts.parts * LANES * floats), np.float32)  # per lane
    overflow = tape_rows.view(np.int32)[:parts.parts * LANES * floats].reshape(
        parts.parts, -1, LANES)[:, OVERFLOW] if covers and floats else None
    if overflow is not None:
        overflow[:] = -1  # a lane whose bounce loop outran the tape writes its count
    buffers = dict(zip(SCENE_BUFFERS, scene.buffers.args()))
    uniform = buffers | {"D": D, "PRM": prm, "gPRM": parts.gPRM, "gT": parts.gT,
                         "ad_tape": tape_rows}
    j = np.arange(cells * batch, dtype=np.int32)
    ones = np.ones(j.size, np.float32)  # every seed: d (sum of the kernel's result) = 1
    for done in range(0, spp, batch):
        n = cells * min(batch, spp - done)
        varying = {"j": j[:n], "ad_row": parts.rows(n, prm.size),
                   "ad_row_tape": parts.rows(n, floats, interleaved=True),
                   "ad_row_T": parts.rows(n, scene.buffers.T.size)
                   if parts.texels else np.zeros(n, np.int32)}
        uniform["BATCH"] = batch_row(done, spp, seed)
        parts.run(mod["render_sample_loss"], [varying[x] if x in varying else uniform[x]
                                              if x in uniform else _seed(x, ones[:n])
                                              for x in names], n)
    if overflow is not None and (overflow != -1).any():  # the tape did not cover: again,
        scene._tape_overflowed = True  # with a kernel that replays (and from now on)
        return backward(scene, d_img, params, spp, seed, threads, eliminate, tape)
    return {name: parts.gradient(c) for name, c in chosen.items()}


def tape_covers(scene: Scene, tape: int) -> bool:
    """Whether the adjoint kernel may leave out the iterations beyond the tape
    (``Build.tape_covers``): the integrator's ``max_depth`` keeps its bounce loop under
    ``tape`` iterations, and no pass of this scene outran such a tape before.  (A lane that
    outruns it anyway, in a loop ``max_depth`` does not bound, is caught: ``backward`` runs
    again without.)"""
    if tape <= 0 or getattr(scene, "_tape_overflowed", False):
        return False
    slots = scene.params.slots
    for name in integrator_names(scene):
        key = f"{name}.max_depth"
        if key in slots:
            return 0 <= int(scene.params[key][0]) < tape
    return False


def _seed(name: str, ones: np.ndarray) -> np.ndarray:
    """The adjoint seed ``a_ret_*`` of a channel of ``render_sample_loss``'s result."""
    if not name.startswith("a_ret"):
        raise CompileError(f"the adjoint render kernel has an argument `{name}` that "
                           "backward does not know")
    return ones


class _Parts:
    """The adjoint pass split into parts of whole packets, each with ``LANES`` rows of its
    own in each gradient buffer: lane k of a packet adds into row k of its part, so no two
    lanes running at once add into one element (no atomics), and the buffers stay small
    (parts x LANES rows, not one per sample).  The parts shrink towards the end of a batch
    (:func:`_bounds`), so that the last one to finish keeps the other cores waiting
    briefly; with texel gradients, whose rows are a texture each, there are fewer.
    Without texel parameters ``gT`` is one row nobody reads (the adjoint kernel writes it
    anyway)."""

    def __init__(self, prm: np.ndarray, T: np.ndarray, texels: bool,
                 threads: int | None, sizes: list[int]) -> None:
        self.threads = max(1, int(threads or os.cpu_count() or 1))
        self.texels = texels
        self.parts = max(len(_bounds(self.threads, texels, n)) for n in sizes)
        rows = self.parts * LANES
        if rows * max(T.size if texels else 0, prm.size) >= 2 ** 31:
            raise ValueError(f"texel gradients of {T.size} floats in {rows} rows exceed "
                             "32-bit indices; use fewer threads")
        self.gPRM = np.zeros(rows * prm.size, np.float32)
        self.gT = np.zeros(rows * T.size if texels else T.size, np.float32)

    def rows(self, n: int, size: int, interleaved: bool = False) -> np.ndarray:
        """The first element of each sample's row, in a buffer of rows of ``size``; with
        ``interleaved`` (the tape's: compiler/passes/ad_checkpoint.py) lane k of a part's
        block starts at ``k`` and its value j is ``TAPE_LANES`` further on each time.
        (Read-only: the same arrays serve every pass of the same shape.)"""
        return _rows(self.threads, self.texels, n, size, interleaved)

    def run(self, kernel, args: list, n: int) -> None:
        """``kernel`` over a batch of ``n`` samples, one task per part on ``threads``
        threads (the kernels' long-lived pool): one call, so its arguments are converted
        once, not once per part (0.4 ms each here)."""
        kernel(*args, threads=self.threads, ranges=_bounds(self.threads, self.texels, n))

    def gradient(self, chosen: Slot | Texels) -> np.ndarray:
        if isinstance(chosen, Texels):
            total = self.gT.reshape(self.parts * LANES, -1).sum(0, dtype=np.float64)
            g = sum(total[off:off + chosen.size] / scale for off, scale in chosen.copies)
            return np.asarray(g, np.float32).reshape(chosen.shape)
        total = self.gPRM.reshape(self.parts * LANES, -1).sum(0, dtype=np.float64)
        return total[chosen.offset:chosen.offset + chosen.size].astype(np.float32)


def _bounds(threads: int, texels: bool, n: int) -> list[tuple[int, int]]:
    """[lo, hi) of each part of [0, n), of whole packets: all of it on one thread; with
    texel gradients ``PARTS_PER_THREAD_TEXELS`` equal parts per thread; else parts of a
    ``GUIDED``-th of what is left each (at least ``MIN_PART`` samples), so that the last
    parts are short (about 20 parts for 2 threads and 262k samples)."""
    if threads == 1:
        return [(0, n)]
    if texels:
        per = -(-n // (threads * PARTS_PER_THREAD_TEXELS))
        step = -(-per // LANES) * LANES
        return [(lo, min(lo + step, n)) for lo in range(0, n, step)]
    out, lo = [], 0
    while lo < n:
        step = max(MIN_PART, -(-(n - lo) // (GUIDED * threads)))
        step = -(-step // LANES) * LANES
        out.append((lo, min(lo + step, n)))
        lo += step
    return out


@lru_cache(maxsize=32)
def _rows(threads: int, texels: bool, n: int, size: int, interleaved: bool) -> np.ndarray:
    """:meth:`_Parts.rows` (an optimization loop asks for the same ones every iteration)."""
    rows = np.empty(n, np.int32)
    for p, (lo, hi) in enumerate(_bounds(threads, texels, n)):
        lane = np.arange(hi - lo) % LANES
        rows[lo:hi] = p * LANES * size + (lane if interleaved else lane * size)
    rows.flags.writeable = False
    return rows
