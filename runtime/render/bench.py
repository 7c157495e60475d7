"""``rdsl bench SCENE``: render time against error.  The scene is rendered at increasing spp
(``--spp 1,4,16,64``, or doubling until a render takes ``--seconds``) for each target and
variant asked, each image's RMSE taken against a reference, and the curve of RMSE against
wall seconds printed as a table and drawn as a log-log plot (``-o PLOT.png``, matplotlib).

The reference is ``--ref REF.exr``; else rendered once at 16x the largest spp (by Mitsuba 3
with ``--vs mitsuba``, else by rdsl in each variant) and cached under the kernel cache
(``$RDSL_CACHE_DIR/bench_ref``), never beside the user's files.  ``--vs mitsuba`` renders
Mitsuba 3 at the same spp, the two renderers taking turns run by run, so that a change in a
shared machine's load hits both alike: ``llvm_ad_*`` where libLLVM 19 is found
(``DRJIT_LIBLLVM_PATH``), else ``scalar_*``; the table names the variant.

The helpers :func:`rmse`, :func:`interleaved_medians` and :func:`mitsuba_variant` serve the
scripts under ``bench/`` as well."""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ...compiler.diagnostics import CompileError
from .cli import scene_file, thread_count

LIBLLVM = Path("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")
REF_FACTOR = 16  # the reference's spp: this times the largest spp measured


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """Root mean square difference of the RGB channels of two images."""
    return float(np.sqrt(np.mean((a[..., :3].astype(np.float64) - b[..., :3]) ** 2)))


def interleaved_medians(fns: dict[str, Callable[[int], np.ndarray]], repeat: int,
                        runs: dict[str, list[float]] | None = None,
                        images: dict[str, list[np.ndarray]] | None = None
                        ) -> dict[str, tuple[float, float, np.ndarray]]:
    """Median wall seconds, median CPU seconds (all the process's threads) and the last image
    of each renderer in ``fns``, after a warm-up (compilation, caches, page faults).  The
    renderers take turns, one run each per repeat, so a change in the machine's load (it is
    shared) hits them alike; CPU seconds hardly change with the load at all.  ``runs``, if
    given, receives each renderer's wall seconds run by run; ``images`` every image (the
    warm-up's first: seeds 0 .. ``repeat``)."""
    imgs = {name: fn(0) for name, fn in fns.items()}
    every: dict[str, list[np.ndarray]] = {name: [img] for name, img in imgs.items()}
    times: dict[str, list[float]] = {name: [] for name in fns}
    cpus: dict[str, list[float]] = {name: [] for name in fns}
    for k in range(repeat):
        for name, fn in fns.items():
            t, c = time.perf_counter(), time.process_time()
            imgs[name] = fn(k + 1)
            times[name].append(time.perf_counter() - t)
            cpus[name].append(time.process_time() - c)
            every[name].append(imgs[name])
    if runs is not None:
        runs.update(times)
    if images is not None:
        images.update(every)
    return {name: (statistics.median(times[name]), statistics.median(cpus[name]), imgs[name])
            for name in fns}


def mitsuba_variant(color: str = "rgb") -> str:
    """Select and name Mitsuba 3's ``llvm_ad_<color>`` variant, else ``scalar_<color>``
    (libLLVM 19 missing).  Raises ImportError without the ``mitsuba`` package."""
    if LIBLLVM.is_file():
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", str(LIBLLVM))
    import mitsuba as mi

    for v in (f"llvm_ad_{color}", f"scalar_{color}"):
        try:
            mi.set_variant(v)
            return v
        except Exception:  # noqa: BLE001,S112 - libLLVM missing: the next variant
            continue
    raise ImportError(f"Mitsuba 3 has neither llvm_ad_{color} nor scalar_{color}")


def add_commands(sub: argparse._SubParsersAction) -> dict[str, Callable[[Any], int]]:
    """Add ``bench`` to ``sub``; returns its handler by name."""
    b = sub.add_parser("bench", help="render time against error (RMSE), as a table and a "
                       "log-log plot")
    b.add_argument("scene")
    b.add_argument("--ref", default=None, metavar="REF.exr",
                   help="the reference image (default: rendered at 16x the largest spp, by "
                        "Mitsuba 3 with --vs mitsuba, else by rdsl; cached)")
    b.add_argument("--vs", choices=("mitsuba",), default=None,
                   help="also render Mitsuba 3 at the same spp, taking turns run by run")
    b.add_argument("--targets", default="host", help="comma-separated (default: host)")
    b.add_argument("--variants", default="rgb", help="comma-separated (default: rgb)")
    b.add_argument("--spp", default=None, help="comma-separated (default: 1,4,16,64)")
    b.add_argument("--seconds", type=float, default=None, metavar="S",
                   help="instead of --spp: 1, 2, 4, ... spp until a render takes S seconds")
    b.add_argument("--repeat", type=int, default=1,
                   help="timed runs per point after a warm-up, the median kept (default 1)")
    b.add_argument("--threads", type=thread_count, default=None, help="default: all cores")
    b.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="set a scene parameter declared with <default>")
    b.add_argument("-o", "--output", default=None, metavar="PLOT.png",
                   help="write the log-log plot of RMSE against seconds (needs matplotlib)")
    return {"bench": bench_command}


def _names(text: str, what: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise CompileError(f"--{what}: expected a comma-separated list, got `{text}`")
    return names


def _spp_list(args: Any) -> list[int] | None:
    """The spp asked, or None for ``--seconds`` (1, 2, 4, ... until a render is that long)."""
    if args.seconds is not None:
        if args.spp is not None:
            raise CompileError("give --spp or --seconds, not both")
        if args.seconds <= 0:
            raise CompileError(f"--seconds: expected a positive number, got {args.seconds}")
        return None
    text = args.spp or "1,4,16,64"
    try:
        spp = [int(s) for s in _names(text, "spp")]
    except ValueError:
        raise CompileError(f"--spp: expected comma-separated integers, got `{text}`") from None
    if min(spp) < 1:
        raise CompileError(f"--spp: expected positive integers, got `{text}`")
    return sorted(set(spp))


def _check_plot(out: str | None, scene: Path) -> Path | None:
    """The plot's path, after checking that matplotlib is there and the path is sane."""
    if out is None:
        return None
    path = Path(out)
    if path.suffix.lower() != ".png":
        raise CompileError(f"{path}: the plot is a PNG; name it *.png")
    if path.resolve() == scene.resolve():
        raise CompileError(f"{path}: refusing to overwrite the input scene")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CompileError("-o needs matplotlib, which is not installed "
                           "(pip install matplotlib, or pip install -e '.[bench]')") from None
    return path


class Curve:
    """One renderer x target x variant: a render function and its points (spp, s, image)."""

    def __init__(self, renderer: str, target: str, variant: str,
                 render: Callable[[int, int], np.ndarray]) -> None:
        self.renderer, self.target, self.variant = renderer, target, variant
        self.render = render
        self.points: list[tuple[int, float, np.ndarray]] = []
        self.shape: tuple[int, int] = (0, 0)  # the image's (height, width)

    @property
    def label(self) -> str:
        return f"{self.renderer} {self.target} {self.variant}"


def rdsl_curves(scene: Path, targets: list[str], variants: list[str],
                defines: dict[str, str], threads: int | None) -> list[Curve]:
    """A curve per target x variant, each scene loaded and its kernels compiled."""
    from ...compiler.build import Build
    from ...compiler.targets import host_supports
    from .renderer import load_scene

    builds = [(t, v, Build.of(t, v)) for t in targets for v in variants]  # names checked
    for t, _, build in builds:
        if not host_supports(build.target):
            raise CompileError(f"--targets: this machine cannot run target `{t}`")
    curves = []
    for t, v, build in builds:
        s = load_scene(scene, build=build, **defines)
        s.compile()
        c = Curve("rdsl", build.target.name, v,
                  lambda spp, seed, s=s: s.render(spp=spp, seed=seed, threads=threads)[..., :3])
        c.shape = (int(s.desc.sensor.film["height"]), int(s.desc.sensor.film["width"]))
        curves.append(c)
    return curves


def mitsuba_curve(scene: Path, variant: str, defines: dict[str, str],
                  threads: int | None) -> Curve:
    """Mitsuba 3 rendering ``scene`` in the colour model ``variant`` (rgb or spectral)."""
    if variant not in ("rgb", "spectral"):
        raise CompileError(f"--vs mitsuba: Mitsuba 3 has no counterpart of variant `{variant}`"
                           " here (rgb, spectral)")
    try:
        mv = mitsuba_variant(variant)
    except ImportError as e:
        raise CompileError(f"--vs mitsuba: Mitsuba 3 is not usable ({e}); pip install "
                           "mitsuba") from None
    import drjit as dr
    import mitsuba as mi

    if threads and mv.startswith("llvm"):
        dr.set_thread_count(threads)
    try:
        sc = mi.load_file(str(scene), **defines)
    except Exception as e:  # noqa: BLE001 - Mitsuba's own message, on one line
        msg = str(e).strip().splitlines()
        raise CompileError(f"{scene}: Mitsuba 3 cannot load it: "
                           f"{msg[-1] if msg else type(e).__name__}") from None

    def render(spp: int, seed: int) -> np.ndarray:
        mi.set_variant(mv)  # another variant may have been selected since
        return np.array(mi.render(sc, spp=spp, seed=seed))[..., :3]
    return Curve("mitsuba", mv, variant, render)


def measure(curves: list[Curve], spp: list[int] | None, seconds: float | None,
            repeat: int) -> None:
    """Render every curve at each spp, the curves taking turns; with ``spp`` None, at 1, 2,
    4, ... until a render of some curve takes ``seconds``."""
    todo = list(spp) if spp is not None else [1]
    while todo:
        n = todo.pop(0)
        fns = {str(i): (lambda seed, c=c, n=n: c.render(n, seed)) for i, c in enumerate(curves)}
        res = interleaved_medians(fns, repeat)
        for i, c in enumerate(curves):
            wall, _, img = res[str(i)]
            c.points.append((n, wall, img))
        slowest = max(res[k][0] for k in res)
        if spp is None and slowest < seconds and n < 1 << 16:
            todo.append(2 * n)


def reference(scene: Path, curve: Curve, spp: int, defines: dict[str, str]) -> np.ndarray:
    """``curve``'s renderer at ``spp``, cached under the kernel cache by the scene's text,
    the -D values, the renderer, its variant and spp."""
    from ... import __version__
    from ..cache import cache_dir
    from .image import read_exr, write_exr

    key = hashlib.sha256(b"\0".join([
        scene.read_bytes(), repr(sorted(defines.items())).encode(),
        f"{curve.renderer} {curve.target} {curve.variant} {spp} {__version__}".encode()]))
    file = cache_dir() / "bench_ref" / f"{scene.stem}_{key.hexdigest()[:16]}.exr"
    if file.is_file():
        print(f"reference: {curve.label} at {spp} spp (cached: {file})", flush=True)
        return read_exr(file)[..., :3]
    t = time.perf_counter()
    img = curve.render(spp, 1_000_003)
    print(f"reference: {curve.label} at {spp} spp, {time.perf_counter() - t:.1f} s "
          f"(cached: {file})", flush=True)
    file.parent.mkdir(parents=True, exist_ok=True)
    tmp = file.with_suffix(f".{os.getpid()}.tmp.exr")
    write_exr(tmp, img.astype(np.float32))
    os.replace(tmp, file)
    return img


def read_reference(path: str, shape: tuple[int, int]) -> np.ndarray:
    """The image of ``--ref``, checked to be ``shape`` (height, width)."""
    from .image import read_exr

    if not Path(path).is_file():
        raise CompileError(f"{path}: no such reference image")
    try:
        img = read_exr(path)
    except OSError as e:
        raise CompileError(f"{path}: {e}") from None
    if img.shape[:2] != shape:
        raise CompileError(f"{path}: the reference is {img.shape[1]}x{img.shape[0]}, but the "
                           f"scene renders {shape[1]}x{shape[0]}")
    if img.ndim != 3 or img.shape[2] < 3:
        raise CompileError(f"{path}: the reference has no RGB channels")
    return img[..., :3]


def write_plot(path: Path, curves: list[Curve], errors: dict[str, list[float]],
               title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for c in curves:
        style = "o-" if c.renderer == "rdsl" else "s--"
        ax.loglog([p[1] for p in c.points], errors[c.label], style, label=c.label)
        for (spp, t, _), e in zip(c.points, errors[c.label]):
            ax.annotate(str(spp), (t, e), textcoords="offset points", xytext=(4, 4),
                        fontsize=7)
    ax.set_xlabel("render time (s, wall)")
    ax.set_ylabel("RMSE against the reference")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100, bbox_inches="tight")
    except OSError as e:
        raise CompileError(f"{path}: cannot write the plot: {e.strerror or e}") from None
    finally:
        plt.close(fig)


def bench_command(args: Any) -> int:
    from ..scene.xml import parse_defines

    scene = scene_file(args.scene)
    spp = _spp_list(args)
    if args.repeat < 1:
        raise CompileError(f"--repeat: expected a positive integer, got {args.repeat}")
    targets, variants = _names(args.targets, "targets"), _names(args.variants, "variants")
    plot = _check_plot(args.output, scene)
    defines = parse_defines(args.defines)
    curves = rdsl_curves(scene, targets, variants, defines, args.threads)
    shape = curves[0].shape
    ref = read_reference(args.ref, shape) if args.ref else None
    if args.vs == "mitsuba":
        curves += [mitsuba_curve(scene, v, defines, args.threads) for v in variants]
    measure(curves, spp, args.seconds, args.repeat)
    top = max(p[0] for c in curves for p in c.points)
    refs: dict[str, np.ndarray] = {}
    if ref is None:  # one per variant: rgb and spectral converge to different images
        by = [c for c in curves if c.renderer == ("mitsuba" if args.vs else "rdsl")]
        for v in variants:
            first = next(c for c in by if c.variant == v)
            refs[v] = reference(scene, first, REF_FACTOR * top, defines)
    errors = {c.label: [rmse(img, ref if ref is not None else refs[c.variant])
                        for _, _, img in c.points] for c in curves}
    _print_table(curves, errors)
    if plot is not None:
        what = args.ref or f"{'Mitsuba 3' if args.vs else 'rdsl'} at {REF_FACTOR * top} spp"
        write_plot(plot, curves, errors, f"{scene.name} {shape[1]}x{shape[0]}: RMSE against "
                   f"{what}")
        print(f"plot: {plot}")
    return 0


def _print_table(curves: list[Curve], errors: dict[str, list[float]]) -> None:
    rows = [(c.renderer, c.target, c.variant, str(spp), f"{t:.4f}", f"{e:.5f}")
            for c in curves for (spp, t, _), e in zip(c.points, errors[c.label])]
    head = ("renderer", "target", "variant", "spp", "seconds", "RMSE")
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    for r in [head, *rows]:
        print("  ".join(x.ljust(w) if i < 3 else x.rjust(w)
                        for i, (x, w) in enumerate(zip(r, widths))).rstrip())
