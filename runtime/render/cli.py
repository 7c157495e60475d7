"""``rdsl render``: load a scene, compile its kernels (or load them from the cache), render
with a progress bar, write EXR plus a PNG preview, and end with a one-line summary; with
``--watch``, go on rendering on each change of the scene or its plugins (watch.py).

:func:`add_commands` declares the subcommand on the top-level parser of ``rdsl/cli.py``."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...compiler.diagnostics import CompileError
from ...core.color import VARIANTS
from .image import write_render
from .stand_in import is_stand_in, tier_words
from .progress import summary_line


def _count(text: str, what: str) -> int:
    """A whole number, 1 or more, of ``what`` (argparse prints the message)."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a number of {what}, 1 or more, got `{text}`")
    return n


def thread_count(text: str) -> int:
    """``--threads``: a whole number of threads, 1 or more."""
    return _count(text, "threads")


def scene_file(text: str) -> Path:
    """The scene argument of ``rdsl render`` and ``rdsl bench``: an existing file."""
    path = Path(text)
    if path.is_dir():
        raise CompileError(f"{path}: is a folder; expected a Mitsuba 3 XML scene file")
    if not path.is_file():
        raise CompileError(f"{path}: no such scene file")
    return path


def sample_total(text: str) -> int:
    """``--spp``: a whole number of samples per pixel, 1 or more."""
    return _count(text, "samples per pixel")


def seed_value(text: str) -> int:
    """``--seed``: a whole number in 0 .. 2^32 - 1 (Mitsuba's seed is a UInt32)."""
    try:
        n = int(text)
    except ValueError:
        n = -1
    if not 0 <= n < 1 << 32:
        raise argparse.ArgumentTypeError(f"expected a whole number in 0 .. 4294967295, got "
                                         f"`{text}`")
    return n


def add_commands(sub: argparse._SubParsersAction) -> dict[str, Callable[[Any], int]]:
    """Add ``render`` to ``sub``; returns its handler by name."""
    r = sub.add_parser("render", help="render a Mitsuba 3 XML scene")
    r.add_argument("scene")
    r.add_argument("-o", "--output", default=None,
                   help="output EXR (default: the scene's name + .exr in the current "
                        "folder); a tonemapped PNG is written beside it")
    r.add_argument("--spp", type=sample_total, default=None, help="samples per pixel (default: the "
                   "scene's sampler)")
    r.add_argument("--seed", type=seed_value, default=None)
    r.add_argument("--target", default="host")
    r.add_argument("--variant", default="rgb",
                   help=", ".join(VARIANTS) + " (default: rgb)")
    r.add_argument("--threads", type=thread_count, default=None, help="default: all cores")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="set a scene parameter declared with <default>")
    r.add_argument("--report", action="store_true",
                   help="print what specialization did and the kernel sizes")
    r.add_argument("--specialize", action=argparse.BooleanOptionalAction, default=None,
                   help="--no-specialize: the generic build, parameters read at run time, "
                        "every emitter kind (default: specialized, generic with --watch)")
    r.add_argument("--triangulate", action="store_true",
                   help="render spheres and disks as triangle meshes, not analytic shapes")
    r.add_argument("--accel", choices=("embree", "bvh"), default=None,
                   help="trace rays with Embree (the default on the LLVM CPU targets) or with "
                        "the BVH written in rdsl (stdlib/render/bvh.rdsl; the default on c, "
                        "opencl, spirv and ptx)")
    r.add_argument("--plugins", action="append", default=[], metavar="DIR",
                   help="a folder (or .rdsl file) of BSDF, texture and emitter plugins, "
                        "searched after the scene's folder (repeatable; also "
                        "$RDSL_PLUGIN_PATH)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--watch", action="store_true",
                   help="after the image, render again whenever the scene, a file it reads "
                        "or a plugin's .rdsl source changes, until Ctrl-C")
    return {"render": render_command}


def render_command(args: Any) -> int:
    from ...compiler.build import Build
    from ..scene.xml import parse_defines
    from .renderer import load_scene

    if args.target == "ptx":  # a CUDA GPU runs the kernels, or nothing does
        from ...compiler.targets import ptx_target
        from ..cuda import cuda_status, device_arch

        reason = cuda_status()
        if reason is not None:
            print(f"rdsl render: --target ptx needs a CUDA GPU: {reason}", file=sys.stderr)
            return 1
        args.target = ptx_target(device_arch())
        args.accel = "bvh"  # Embree runs on the CPU: GPU rays go through the BVH in rdsl
    build = Build.of(args.target, args.variant)  # a bad name fails before the scene loads
    scene_path = scene_file(args.scene)
    out = Path(args.output) if args.output else Path(scene_path.stem + ".exr")
    if out.suffix.lower() != ".exr":
        out = out.with_suffix(".exr")
    for target in (out, out.with_suffix(".png")):
        if target.resolve() == scene_path.resolve():
            raise CompileError(f"{target}: refusing to overwrite the input scene")
    defines = parse_defines(args.defines)
    watching = getattr(args, "watch", False)
    specialize = getattr(args, "specialize", None)
    if specialize is None:  # --watch: editing a parameter value then never compiles
        specialize = not watching

    t0 = time.perf_counter()
    scene = load_scene(scene_path, build=build, specialize=specialize,
                       triangulate=getattr(args, "triangulate", False),
                       plugins=getattr(args, "plugins", []),
                       accel=getattr(args, "accel", None), **defines)
    t_load = time.perf_counter() - t0
    integ = scene.desc.integrator
    lit = [i for i in [integ, *integ.children] if i.type in ("path", "direct")
           and (i.decl is None or i.decl.stdlib)]  # a user's integrator may need no light
    if not scene.buffers.nlight and lit:
        print(f"{scene_path}: warning: the scene has no emitters; the image will be black",
              file=sys.stderr)
    spp = args.spp or scene.spp
    mod = scene.compile(quick=scene.quick_fits(spp))
    how = "kernels from cache" if scene.from_cache else \
        f"compiled in {scene.compile_seconds:.2f} s"
    how += (" (generic build standing in)" if is_stand_in(mod)
            else " (quick tier)" if getattr(mod, "quick", False) else "")
    if args.report:
        _print_report(scene, mod)
    t1 = time.perf_counter()
    img = scene.render(spp=spp, seed=args.seed, threads=args.threads,
                       progress=not args.quiet)
    t_render = time.perf_counter() - t1
    if scene.nonfinite:
        own = sorted({str(d.path) for d in scene.desc.plugins.values() if not d.stdlib})
        hint = (f" (the scene's own plugins, which `rdsl test-plugin FILE` sweeps for NaN: "
                f"{', '.join(own)})" if own else "")
        print(f"warning: {scene.nonfinite} samples were NaN or infinite and were left out of "
              f"the image{hint}", file=sys.stderr)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        png = write_render(out, img, scene.channel_names)
    except OSError as e:
        raise CompileError(f"{out}: cannot write the image: {e.strerror or e}") from None
    h, w = img.shape[:2]
    paths = h * w * spp
    print(summary_line(f"{scene_path.name}: {w}x{h}, {spp} spp", t_render, paths, "paths",
                       f"scene {t_load:.2f} s, {how}; wrote {out} and {png.name}"), flush=True)
    if not watching:
        return 0
    from .watch import WatchJob, watch

    return watch(scene, WatchJob(out, args.spp, args.seed, args.threads, t_render / spp))


def _print_report(scene: Any, mod: Any) -> None:
    """``--report``: what specialization did, and the kernels' sizes."""
    for line in scene.report:
        print(f"specialize: {line}")
    spec, generic = scene.instruction_counts()
    print(f"render_sample: {spec} instructions specialized, " + (
        f"{generic} generic ({100 * (spec - generic) / generic:+.0f}%)" if generic is not None
        else "no generic build (an integer parameter of 2**24 or more)"))
    k = mod.manifest["kernels"]
    tier = tier_words(mod)
    print(f"kernels: {', '.join(x['name'] for x in k)} for `{mod.target}` "
          f"(width {mod.width}, variant {scene.build.model.name}), {tier}")
