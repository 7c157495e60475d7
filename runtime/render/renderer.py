"""Render a Mitsuba scene with compiled rdsl kernels.

Python's part is set-up and bookkeeping only: it loads the scene, flattens its triangles
into buffers, builds the Embree scene, has the scene's render kernel written (the template
stdlib/render/kernel.rdsl.in filled in by kernel_source.py: the stdlib integrator, camera
and film called with the scene's constants) and runs it in batches of samples.  Every
per-sample computation happens in compiled rdsl code: camera rays, intersection (Embree,
called from the kernel), shading, light sampling and the film's reconstruction filter.
"""

from __future__ import annotations

import hashlib
import os
import time
import warnings
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.backends.c_like import NoRayTracer
from ...compiler.build import Build
from ...compiler.diagnostics import CompileError
from ...compiler.passes.ad_forward import TANGENT_BUFFER
from ...compiler.passes.specialize import (
    PARAM_BUFFER,
    SlotRangeError,
    describe,
    parameter_slots,
)
from ...compiler.targets import Target
from ...core.color import ColorModel
from ...core.scene_spec import SceneSpec
from ..scene import load_scene_description
from ..scene.reads import recording
from ..scene.samplers import requested_samples, sample_count
from ..tables import fill_tables
from .stand_in import after_render, generic_stand_in, is_stand_in, wait_for_generic_build
from .bsdfs import (
    dispersion_warnings,
    polarization_warnings,
    split_leaves,
)
from .bvh import scene_bvh
from .differentiable import SceneParams, gradient, render_forward
from .emitters import KINDS as EMITTER_KINDS
from .film import (COLOUR_CHANNELS, colour_image, develop, film_format, film_uniforms,
                   gather_in_groups, new_accumulator)
from .flatten import SceneBuffers, flatten
from .integrators import integrator_instances, integrator_plan
from .kernel_source import batch_row, film_channels, kernel_source, scene_plugins
from .prebuild import wait_for_speculated
from .progress import Progress
from .shapes import FLAGS as SHAPE_FLAGS
from .shapes import INSTANCED, INSTANCED_KIND
from .shapes import KINDS as SHAPE_KINDS

ACCELS = ("embree", "bvh")  # how rays are traced (`--accel`)
# samples per kernel call: small enough that a batch's sample buffers stay in cache
BATCH_SAMPLES = 1 << 17
# renders of at most this many samples, whose kernels are not in the cache yet, compile the
# quick tier (LLVM O0): it saves about 40% of a cold compile, more than its slower kernels
# (15-30%) lose on a render of this size (docs/bench.md)
QUICK_SAMPLES = 1 << 21


class RenderCancelled(Exception):
    """``Scene.render``'s ``cancel`` asked it to stop."""


# scenes of fewer triangles than this are traced through two levels of BVH
TWO_LEVEL_TRIANGLES = 1000


def _bvh_quality(bufs: SceneBuffers) -> str:
    """Embree's build quality for the scene.  "low": two levels, a BVH per shape under one
    over the shapes; scenes of a few large shapes, such as the Cornell box (36 triangles),
    trace about a third faster that way than through one BVH over all triangles.  "high":
    one BVH with spatial splits, which traces meshes of many triangles faster (AMD EPYC,
    64 spp, bench/scene_set.py in two alternated runs of each build: bigmesh 0.367, 0.327 ->
    0.320, 0.298 s, matpreview_diffuse 0.276, 0.277 -> 0.263, 0.254 s; the Cornell box went
    from 0.96-1.09 s to 1.31 s, so it keeps two levels) and builds in 0.07 s for 100k
    triangles."""
    triangles = sum(len(m[1]) for m in bufs.meshes if not hasattr(m, "new_geometry"))
    return "low" if triangles < TWO_LEVEL_TRIANGLES else "high"


def _geometry_key(bufs: SceneBuffers) -> str:
    """A hash of what the Embree scene is built from: each shape's kind and size, the
    vertices and analytic shapes' records (both in ``P``) and the triangles."""
    h = hashlib.sha256()
    for m in bufs.meshes:
        h.update(repr(tuple(np.shape(a) for a in m) if isinstance(m, tuple)
                      else type(m).__name__).encode())
    h.update(bufs.P.tobytes())
    h.update(bufs.F.tobytes())
    return h.hexdigest()


def _shape_kind(flags: int) -> int:
    """geometry.rdsl's shape kind (0 mesh, 1 sphere, 2 disk, 3 instanced mesh) from G's
    flags."""
    if flags & INSTANCED:
        return INSTANCED_KIND
    return next((SHAPE_KINDS[k] for k, bit in SHAPE_FLAGS.items() if flags & bit), 0)


class Scene:
    """A loaded scene, compiled for one build (target and colour model).  ``render``
    returns the image as a float32 (H, W, C) array."""

    derivative = False  # the forward-mode twin's film also takes d(radiance)
    tangents: np.ndarray | None = None  # its dPRM

    def __init__(self, path: str | Path, build: Build, specialize: bool = True,
                 triangulate: bool = False, plugins: Any = (), accel: str | None = None,
                 **defaults: Any) -> None:
        if accel is None:  # Embree runs on the CPU; other devices trace through the rdsl BVH
            accel = "embree" if build.target.backend == "llvm" else "bvh"
        if accel not in ACCELS:
            raise CompileError(f"unknown accel `{accel}` (valid: {', '.join(ACCELS)})")
        self.path = Path(path)
        self.accel = accel
        self.build = build
        self.specialize = specialize
        self.triangulate = triangulate
        self.plugins = plugins
        self.defaults = defaults
        self._read(None)

    def reload(self) -> Scene:
        """The scene read again from its files (after an edit), as a new Scene.  Mesh and
        image files that did not change are not parsed again, and the Embree scene is
        shared when the geometry is unchanged (``geometry_reused``); the kernels come from
        the cache unless what they are compiled from changed."""
        new = Scene.__new__(Scene)
        new.path, new.build, new.specialize = self.path, self.build, self.specialize
        new.triangulate, new.defaults = self.triangulate, self.defaults
        new.plugins, new.accel = self.plugins, self.accel
        new._read(self)
        return new

    def _read(self, previous: Scene | None) -> None:
        """Load the scene's files, flatten them and build the Embree scene (``previous``:
        the load this one replaces, whose unchanged parts are reused)."""
        from ..embree import EmbreeScene

        model = self.build.model
        t0 = time.perf_counter()
        # self.reads: every file the load read (rdsl render --watch watches them), even
        # when it fails part way
        with recording(previous.reads if previous is not None else None) as self.reads:
            self.desc = load_scene_description(self.path, plugins=self.plugins,
                                               **self.defaults)
            self.spp = int(self.desc.sensor.sampler.params.get("sample_count", 4))
            self.seed = int(self.desc.sensor.sampler.params.get("seed", 0))
            integrator_plan(self.desc.integrator).check_variant(model)
            self.buffers, self.bsdfs, self.emitters = flatten(
                self.desc, self.triangulate, model, instancing=self.accel == "embree")
        for message in [*polarization_warnings(self.desc, model),
                        *dispersion_warnings(self.desc, model)]:
            warnings.warn(message, stacklevel=3)
        self.load_seconds = time.perf_counter() - t0
        self.geometry_key = _geometry_key(self.buffers)
        self.geometry_reused = previous is not None and \
            previous.geometry_key == self.geometry_key
        self.embree = self.bvh = None
        if self.geometry_reused:
            self.embree, self.bvh = previous.embree, previous.bvh
            self.buffers.BV, self.buffers.BI = previous.buffers.BV, previous.buffers.BI
        elif self.accel == "bvh":  # traversal in rdsl (stdlib/render/bvh.rdsl)
            self.buffers.BV, self.buffers.BI, self.bvh = scene_bvh(self.buffers)
        else:
            self.embree = EmbreeScene(self.buffers.meshes, quality=_bvh_quality(self.buffers),
                                      mesh_quality="high")
        self.prm = np.zeros(1, np.float32)  # PRM of the generic build
        self._prm_set = False  # a value of PRM was assigned (scene.params[...] = ...)
        self._reset_kernels()
        self.report: list[str] = []
        self.compile_seconds = 0.0
        self.from_cache = False
        self.nonfinite = 0

    def compile(self, again: bool = False, quick: bool = False):
        """Compile (or load from the cache) the scene's kernels; ``again``: even if they
        were (a source they import changed: the cache key tells whether it did).  ``quick``:
        the quick tier will do (:func:`rdsl.runtime.api.jit`), unless the full one is cached
        or loaded already; without it, quick kernels loaded before are replaced."""
        from ...runtime.api import jit, jit_cached, quick_everywhere

        small = quick  # a render the quick tier's size: the generic build may stand in
        quick = quick or quick_everywhere()  # RDSL_QUICK=1: the full tier is never built
        # a PTX module has no tiers; a generic stand-in is replaced as the quick tier is
        loaded_quick = getattr(self._module, "quick", False) or is_stand_in(self._module)
        if self._module is not None and not again and (quick or not loaded_quick):
            return self._module
        src, kw = self._jit_inputs = self._jit_args()
        wait_for_speculated(self, quick)  # a background build of these kernels (prebuild.py)
        wait_for_generic_build(src, kw, quick)  # or stand_in.py's, of the generic ones
        try:  # a small render not cached yet: the generic build's kernels (stand_in.py)
            mod = generic_stand_in(self, small, src, kw) or \
                jit(src, quick=quick and not jit_cached(src, **kw), **kw)
        except NoRayTracer:  # one line: what is missing, not the integrator's source
            raise CompileError(_no_ray_tracer(self.path, self.build.target.name)) from None
        if not self.specialize:  # and so do the tables the plugins compute per scene
            self.prm = self.with_tables(self.prm, mod)
        self._module = mod
        self.compile_seconds = mod.compile_seconds
        self.from_cache = mod.from_cache
        return mod

    def _jit_args(self) -> tuple[str, dict[str, Any]]:
        """What :func:`rdsl.runtime.api.jit` builds the render kernels from: the source
        and its options (but the tier)."""
        src, scene, filename = self._kernel_inputs()
        kw = {"build": self.build, "scene": scene, "search_paths": self.search_paths,
              "filename": filename}
        if self.build.ad == "reverse":  # backward runs this kernel's adjoint and the film-weight
            # kernels (their adjoints differentiate nothing: no parameter reaches them)
            kw["exports"] = ["render_sample_loss", "film_weight_sample", "film_weight_pass"]
        return src, kw

    def _reset_kernels(self) -> None:
        """Forget the loaded kernels (the next render compiles or loads new ones), and
        stop a background build of the old ones' full tier."""
        self._module = None
        if getattr(self, "_tier_up", None) is not None:
            self._tier_up.stop()
        self._tier_up, self._quick_renders = None, 0

    def _tiered(self, mod: Any) -> Any:
        """The kernels a render runs: ``mod``, or the full tier once a background build
        of it is done (runtime/render/tier_up.py); starts that build at the
        ``RENDERS_BEFORE_TIER_UP``-th render with quick-tier kernels."""
        from ...runtime.api import quick_everywhere
        from .tier_up import RENDERS_BEFORE_TIER_UP, TierUp

        if not (getattr(mod, "quick", False) and not quick_everywhere() or is_stand_in(mod)):
            return mod
        if self._tier_up is None:
            if self._quick_renders is not None:  # None: built already (or it failed)
                self._quick_renders += 1
                if self._quick_renders >= RENDERS_BEFORE_TIER_UP:
                    try:
                        self._tier_up = TierUp(*self._jit_inputs)  # what built `mod`
                    except Exception as e:  # noqa: BLE001 - no process to spare, or a
                        # scene that cannot be pickled: an optimization, the render goes on
                        warnings.warn(f"cannot build the full-tier kernels in the "
                                      f"background ({e}); rendering goes on with the quick "
                                      "tier", stacklevel=3)
                        self._quick_renders = None
            return mod
        if not self._tier_up.done():
            return mod
        full = self._tier_up.load()
        self._tier_up, self._quick_renders = None, None
        if full is None:
            return mod
        self._module = full
        return full

    def _kernel_inputs(self) -> tuple[str, SceneSpec, str]:
        """The render kernel's source, what specialize is told about the scene, and the
        file name its diagnostics show; sets the report, kernel_src, scene_spec and
        search_paths (and PRM, for the generic build)."""
        src = kernel_source(self.desc, self.buffers, self.bsdfs, self.emitters,
                            self.build.model, derivative=self.derivative,
                            adjoint=self.build.ad == "reverse")
        scene = self.scene_spec_for_params()
        # the report is derived from the scene, so a cache hit can print it too
        self.report = describe(scene) + self._folding(scene)
        self.kernel_src, self.scene_spec = src, scene
        # the folders of the user plugins the kernel imports
        _, self.search_paths = scene_plugins(self.desc, self.bsdfs, self.emitters,
                                             self.buffers.textures)
        if not self.specialize:  # generic: parameter values come from PRM at run time
            scene, prm = self.parameter_slots(scene)
            if not self._prm_set:
                self.prm = prm
        return src, scene, str(self.path.with_suffix(".rdsl"))

    def kernel_ir(self) -> Any:
        """The render kernels as IR after the whole pipeline for this scene's build (no
        library: what ``emit_ptx`` or ``rdsl compile`` of another target starts from)."""
        from ...compiler.driver import compile_kernels

        src, scene, filename = self._kernel_inputs()
        module, _ = compile_kernels(src, self.build, scene=scene, filename=filename,
                                    search_paths=self.search_paths)
        return module

    def quick_fits(self, spp: int | None = None) -> bool:
        """Whether a render at ``spp`` is small enough for the quick tier of kernels."""
        film = self.desc.sensor.film
        return film["width"] * film["height"] * int(spp or self.spp) <= QUICK_SAMPLES

    def scene_spec_for_params(self) -> SceneSpec:
        """What ``specialize`` is told about the scene: its instances and kinds."""
        bsdfs, leaves = split_leaves(self.bsdfs)  # combinators reach leaves by id
        kinds = tuple(sorted({int(k) for k in self.buffers.lights.EK[0::4]}))
        shapes = tuple(sorted({_shape_kind(int(g)) for g in self.buffers.G[3::4]}))
        return SceneSpec(bsdfs, self.emitters, self.buffers.textures, leaves, kinds, shapes,
                         integrator_instances(self.desc.integrator), self.accel)

    @property
    def params(self) -> SceneParams:
        """The scene's parameters by name (runtime/render/differentiable.py)."""
        if getattr(self, "_params", None) is None or self._params.scene is not self:
            self._params = SceneParams(self)
        return self._params

    def with_tables(self, prm: np.ndarray, mod: Any) -> np.ndarray:
        """``prm`` (a generic build's parameters) with the tables that ``mod``, this scene's
        generic kernels, read filled in: each plugin's precomputed samples for the values
        the scene was loaded with (the differentiated twins take the scene's parameters
        and fill their tables so, whether or not the scene's own generic kernels ran)."""
        src, kw = self._jit_inputs
        return fill_tables(mod, self.scene_spec, prm, src, kw["filename"], self.search_paths)

    def use_generic(self) -> None:
        """Read parameters at run time from now on (a parameter was assigned)."""
        if not self._prm_set:
            self.prm = np.array(self.params.values)
            self._prm_set = True
        if self.specialize:
            self.specialize = False
            self._reset_kernels()

    def render_forward(self, name: str, spp: int | None = None, seed: int | None = None,
                       tangent: Any = None, threads: int | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """The image and its derivative with respect to parameter ``name`` (forward-mode
        AD along ``tangent``): runtime/render/differentiable.py."""
        return render_forward(self, name, spp, seed, tangent, threads)

    def gradient(self, names: list[str], loss_grad: np.ndarray, spp: int | None = None,
                 seed: int | None = None) -> dict[str, np.ndarray]:
        """d loss / d parameter for ``names``, from d loss / d image (forward mode, one
        render per parameter component): runtime/render/differentiable.py."""
        return gradient(self, names, loss_grad, spp, seed)

    def backward(self, d_img: Any, params: list[str], spp: int | None = None,
                 seed: int | None = None, threads: int | None = None,
                 eliminate: bool | int = False, tape: int | None = None
                 ) -> dict[str, np.ndarray]:
        """d loss / d parameter for every name of ``params`` from d loss / d image, by one
        adjoint render (reverse mode): runtime/render/backward.py.  ``eliminate``: build
        the adjoint kernel with graph elimination (True: threshold 10; docs/ad.md);
        ``tape``: bounces checkpointed per lane (default 16; 0: recompute them)."""
        from .backward import TAPE, backward

        return backward(self, d_img, params, spp, seed, threads, eliminate,
                        TAPE if tape is None else int(tape))

    def parameter_slots(self, scene: SceneSpec) -> tuple[SceneSpec, np.ndarray]:
        """The generic build's view of ``scene`` and its parameter buffer
        (:func:`rdsl.compiler.passes.specialize.parameter_slots`); an integer it cannot
        hold is an error at the scene's line that sets it."""
        try:
            return parameter_slots(scene, self.build.model)
        except SlotRangeError as e:
            raise CompileError(f"{e.what}: {e.value} is too large for the generic build and "
                               "the differentiated kernels (their parameter buffer's floats "
                               "hold integers exactly below 2**24); the specialized build "
                               "renders it", self.desc.integer_loc(e.value)) from None

    def _folding(self, scene: SceneSpec) -> list[str]:
        """What the build folds (specialized) or reads at run time (generic), for the report."""
        try:
            values = self.parameter_slots(scene)[1]
        except CompileError:  # an integer only the specialized build can hold
            if not self.specialize:
                raise
            values = []
        n = sum(1 for i in [*scene.bsdfs, *scene.bsdf_leaves, *scene.textures,
                            *scene.emitters, *scene.integrators] if i.params)
        kinds = {v: k for k, v in EMITTER_KINDS.items()}
        have = [kinds[k] for k in scene.emitter_kinds or ()]
        lacks = ", ".join(k for k in EMITTER_KINDS if k not in have) or "no other kind"
        env = self.buffers.lights.env
        plugins = ", ".join(sorted({t.plugin for t in scene.textures})) or "no texture code"
        sky = ("none, the miss branch folds away" if env < 0
               else f"emitter {env} ({kinds[int(self.buffers.lights.EK[4 * env])]})")
        lines = [f"textures: {len(scene.textures)} ({plugins})", f"environment: {sky}"]
        if self.bvh is not None:
            lines.append(f"accel: bvh, {self.bvh.nodes} nodes over {len(self.bvh.prims)} "
                         f"primitives, built in {self.bvh.build_seconds:.2f} s")
        if self.specialize:
            folded = f"sampling code for {lacks} folded away"
            return [f"parameters: {len(values)} values of {n} instance(s) folded as constants",
                    f"emitter kinds: {', '.join(have) or 'none'}; {folded}", *lines]
        read = f"{len(values)} values of {n} instance(s) read from {PARAM_BUFFER} at run time"
        return [f"parameters: generic build, {read}",
                f"emitter kinds: {', '.join(have) or 'none'}; sampling code for {lacks} "
                "folded away (the scene's structure, in both builds)", *lines]

    def _param_args(self, mod: Any) -> list[np.ndarray]:
        """``PRM`` for a generic kernel that reads parameters (none when specialized)."""
        kernel = next(k for k in mod.manifest["kernels"] if k["name"] == "render_sample")
        names = [p["name"] for p in kernel["params"]]
        return [self.prm] * (PARAM_BUFFER in names) + [self.tangents] * (TANGENT_BUFFER in names)

    def instruction_counts(self) -> tuple[int, int | None]:
        """IR instructions of ``render_sample`` after the whole pipeline, specialized and
        generic (compiles both to IR, builds no library: for ``rdsl render --report``);
        None for a generic build the scene's integers do not fit."""
        from ...compiler.driver import compile_kernels

        self.compile(quick=True)  # whichever tier is loaded
        try:
            generic = self.parameter_slots(self.scene_spec)[0]
        except CompileError:
            generic = None
        counts = []
        for scene in (self.scene_spec, generic):
            if scene is None:
                return counts[0], None
            module, _ = compile_kernels(self.kernel_src, self.build, scene=scene,
                                        filename=str(self.path.with_suffix(".rdsl")),
                                        search_paths=self.search_paths)
            counts.append(sum(1 for _ in module.functions["render_sample"].walk()))
        return counts[0], counts[1]

    @property
    def channel_names(self) -> list[str]:
        """The image's channels, as the EXR names them: the film's colour (R, G, B; X, Y, Z;
        or Y, as its ``pixel_format`` and the variant make it), A if the film has alpha, then
        the AOVs of the integrator (runtime/render/integrators.py), then, rendering a
        derivative, its channels (``d.R``...)."""
        names = self._film_channels
        base = 1 if self.build.model.mono else 3
        return COLOUR_CHANNELS[self._film_format[0]] + names[base:]

    @property
    def _film_format(self) -> tuple[str, bool]:
        """(colour, alpha) of the film's ``pixel_format`` in this variant."""
        return film_format(self.desc.sensor.film, self.build.model.mono)

    @property
    def _film_channels(self) -> list[str]:
        """The channels the film accumulates (the colour in the variant's own channels)."""
        return film_channels(self.desc, self.build.model, self.derivative)

    def render(self, spp: int | None = None, seed: int | None = None,
               threads: int | None = None, progress: bool = False,
               cancel: Callable[[], bool] | None = None) -> np.ndarray:
        """The image at ``spp`` samples per pixel.  ``cancel`` is asked after each batch
        of samples has reached the film: once it answers True the render stops with
        :class:`RenderCancelled`, once the batch queued behind it has ended (rdsl render
        --watch drops a render an edit made stale)."""
        spp, seed = requested_samples(spp, seed, self.spp, self.seed)
        spp = sample_count(self.desc.sensor.sampler, spp)
        mod = self._tiered(self.compile(quick=self.quick_fits(spp)))
        if mod.traces_rays:  # a path tracer with max_depth 0 traces none: its image is black
            if self.embree is None:
                raise CompileError("the render kernel traces rays through Embree, but the "
                                   f"scene was loaded with accel `{self.accel}`")
            mod.bind_scene(self.embree)
        film = film_uniforms(self.desc.sensor.film, 1, channels=len(self._film_channels))
        cells = film["grid_w"] * film["grid_h"]
        batch = max(1, min(spp, BATCH_SAMPLES // max(cells, 1)))
        acc = new_accumulator(dict(film, spp=batch))
        scene_args = self._scene_args(mod)
        if hasattr(mod, "resident"):  # OpenCL: the film is accumulated on the device
            acc = mod.resident(acc)
        pixels = np.arange(film["crop_w"] * film["crop_h"], dtype=np.int32)
        self.nonfinite = 0
        bar = Progress(spp, label="rendering", unit="spp", enabled=progress)
        # two batches are in flight: batch k + 1 renders while the film takes batch k
        # (their tasks share the thread pool, so neither waits for the other's last
        # tasks), and batch k + 2 is queued as soon as the film has taken batch k, into
        # batch k's output block (so no batch faults in fresh pages; the last, smaller
        # batch gets a block of its own)
        outs: list[Any] = [None, None]
        j = np.arange(cells * batch, dtype=np.int32)  # a batch's sample indices
        inflight: deque[tuple[Any, int, int]] = deque()  # (pending call, n, block slot)
        done = queued = k = 0
        while queued < spp or inflight:
            while queued < spp and len(inflight) < 2:
                n = min(batch, spp - queued)
                job = mod["render_sample"](j[:cells * n], batch_row(queued, spp, seed),
                                           *scene_args, *self._param_args(mod),
                                           threads=threads,
                                           out=outs[k % 2] if n == batch else None,
                                           wait=False)
                inflight.append((job, n, k % 2))
                queued += n
                k += 1
            job, n, slot = inflight.popleft()
            samples = job.result()
            if n == batch:
                outs[slot] = samples
            ns = len(samples["bad"])
            gather_in_groups(mod["film_pass"], pixels, n, ns, _film_samples(samples, ns), acc,
                             threads)
            self.nonfinite += int(np.count_nonzero(samples["bad"]))
            done += n
            bar.update(done)
            if cancel is not None and cancel():
                for job, _n, _slot in inflight:  # let the queued batches end first
                    job.result()
                bar.finish()
                raise RenderCancelled(f"cancelled after {done} of {spp} spp")
        bar.finish()
        after_render(self)  # a new structure's generic kernels, for later edits: stand_in.py
        acc = acc.get() if hasattr(acc, "get") else acc
        if self._prm_set and not self.derivative:  # for backward: each pixel's total weight
            c = film["channels"]
            self.film_weights = ((spp, seed), acc.reshape(-1, c + 1)[:, c].copy())
        img = develop(acc, dict(film, spp=spp))
        return img if self.build.model.mono else colour_image(img, self._film_format[0])

    def _scene_args(self, mod: Any) -> list[Any]:
        """The scene's buffers for ``mod``'s kernels: the arrays, or on a device target
        (``mod.resident``: OpenCL) their copies on the device, made once per module."""
        if not hasattr(mod, "resident"):
            return self.buffers.args()
        if getattr(self, "_resident", (None,))[0] is not mod:
            self._resident = (mod, [mod.resident(b) for b in self.buffers.args()])
        return self._resident[1]


def _no_ray_tracer(path: Path, target: str) -> str:
    """What a scene that traces rays lacks on a target without Embree."""
    from ...compiler.sources import STDLIB

    if (STDLIB / "render" / "bvh.rdsl").is_file():
        return (f"{path.name}: the scene traces rays, which target `{target}` does with the "
                "BVH written in rdsl only: render with --accel bvh")
    return (f"{path.name}: the scene traces rays, and target `{target}` has no ray tracer "
            "yet (it needs the BVH written in rdsl, stdlib/render/bvh.rdsl, which this build "
            "lacks); render with an LLVM target (--target host)")


def _film_samples(out: dict[str, Any], ns: int) -> np.ndarray:
    """The film's structure-of-arrays sample buffer: the radiance and AOV channels, then the
    filter weights, one row of ``ns`` floats each.  The kernel call allocates its float
    outputs as consecutive rows of one block in exactly this order, so this is normally
    that block itself (no copy)."""
    names = ["value", *sorted((k for k in out if k.startswith("aov")), key=lambda k: int(k[3:])),
             *sorted((k for k in out if k.startswith("w")), key=lambda k: int(k[1:]))]
    rows = [r for k in names for r in np.asarray(out[k]).reshape(ns, -1).T]
    block = rows[0].base
    if block is not None and block.ndim == 2 and block.shape == (len(rows), ns) and \
            block.flags.c_contiguous and all(
                r.ctypes.data == block.ctypes.data + j * ns * 4 for j, r in enumerate(rows)):
        return block.reshape(-1)
    return np.ascontiguousarray(np.stack(rows)).reshape(-1)


def load_scene(path: str | Path, variant: str | ColorModel = "rgb",
               target: str | Target = "host", specialize: bool = True,
               triangulate: bool = False, *, build: Build | None = None,
               plugins: Any = (), accel: str | None = None, **defaults: Any) -> Scene:
    """Load a Mitsuba 3 XML scene for rendering (``-D name=value`` as keyword args).
    ``specialize=False`` gives the generic build (parameters read at run time).  ``build``,
    when given, replaces ``variant`` and ``target``; a bad name of either is a diagnostic
    before the scene is read.  ``plugins``: folders (or ``.rdsl`` files) searched for the
    scene's BSDF, texture and emitter plugins after the scene's own folder and before
    ``$RDSL_PLUGIN_PATH``, the registered plugins and the stdlib (docs/plugins.md).
    ``accel``: "embree" (the default on the LLVM CPU targets) traces rays with Embree, "bvh"
    (the default on c, opencl, spirv and ptx) with the BVH written in rdsl (stdlib/render/bvh.rdsl,
    built by runtime/render/bvh.py)."""
    build = build or Build.of(target, variant)
    return Scene(path, build, specialize=specialize, triangulate=triangulate,
                 plugins=plugins, accel=accel, **defaults)


def load_dict(scene: dict, variant: str | ColorModel = "rgb", target: str | Target = "host",
              specialize: bool = True, *, build: Build | None = None, plugins: Any = (),
              **defaults: Any) -> Scene:
    """Load a scene given as Mitsuba 3's Python dictionary (``mi.load_dict``'s format):
    written out as XML (runtime/scene/dicts.py) under the kernel cache and loaded as
    :func:`load_scene` loads a file, user plugins found in the current folder first."""
    from ..cache import cache_dir
    from ..plugins import PluginRegistry
    from ..scene.dicts import dict_error, dict_to_xml

    build = build or Build.of(target, variant)
    places = [Path.cwd(), *plugins]
    text = dict_to_xml(scene, PluginRegistry.for_scene(None, places))
    folder = cache_dir() / "dicts"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{hashlib.sha256(text.encode()).hexdigest()[:20]}.xml"
    if not path.is_file():
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    try:
        return Scene(path, build, specialize=specialize, plugins=places, **defaults)
    except CompileError as e:
        raise dict_error(e, path) from None
