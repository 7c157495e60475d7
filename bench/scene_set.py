"""rdsl against Mitsuba 3 on a set of scenes (bench/scenes/set/, written by
bench/scenes/make_set.py, and the Cornell box): time ratio, equal-error ratio and time to
first pixel, per scene and as geometric means.

    python bench/scene_set.py [NAME ...] [--spp 32] [--repeat 3] [--ref-spp 1024]
                              [--threads 2] [--ttfp] [--json out/scene_set/run.json]

For each scene both renderers render at --spp, taking turns run by run (median of --repeat
after a warm-up; bench/render_vs_mitsuba.py's ``interleaved_medians``), and the RMSE against
a reference (Mitsuba 3 at --ref-spp, cached under out/scene_set/ref/) is that of the images
of all --repeat + 1 runs, seeds 0 .. --repeat (the root of their mean squared error: one
image's error swings with its fireflies; on veach at 64 spp the MSE of 8 seeds spans 10x,
for either renderer).  The equal-error ratio (t_rdsl * RMSE_rdsl^2) /
(t_mitsuba * RMSE_mitsuba^2) is the ratio of times to reach the same error if
RMSE ~ 1/sqrt(time); below 1 rdsl is faster, and a bias of rdsl against Mitsuba shows up as
a high one.  Mitsuba runs `llvm_ad_rgb` (libLLVM 19:
DRJIT_LIBLLVM_PATH), else `scalar_rgb`; the table says which.

--ttfp: the time to first pixel of a new scene, cold: the whole ``rdsl render --spp 1``
command with an empty kernel cache, against a fresh Python process that imports Mitsuba 3,
loads the scene and renders 1 spp with an empty Dr.Jit kernel cache (HOME in a fresh folder).
Then a new scene of a user who rendered before (only the parsed stdlib kept), and an edited
scene: a copy with one material colour changed (times 0.9), rendered with the
kernel cache the runs before it left, by rdsl and by Mitsuba 3 (whose Dr.Jit cache then
holds its kernels too); each rdsl run starts once the kernel builds the one before left in
the background have ended (a new structure's generic kernels, runtime/render/stand_in.py),
and the table says how long that build went on after the new-scene command.  rdsl's Python modules are byte-compiled first, as pip does when it
installs a package (``PYTHONDONTWRITEBYTECODE`` would otherwise make every run compile them).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "bench" / "scenes"))
os.environ.setdefault("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1")

from rdsl.runtime.render.bench import interleaved_medians, mitsuba_variant, rmse

SET = ROOT / "bench" / "scenes" / "set"
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
OUT = ROOT / "out" / "scene_set"


def all_scenes() -> dict[str, Path]:
    import make_set

    make_set.generate()
    out = {p.stem: p for p in sorted(SET.glob("*.xml"))}
    out["cbox"] = CBOX
    return out


def scene_defaults(path: Path) -> dict[str, int]:
    return {"res": 128} if path == CBOX else {}


def mitsuba_render_fn(path: Path, threads: int):
    import drjit as dr
    import mitsuba as mi

    if "llvm" in mi.variant():
        dr.set_thread_count(threads)
    sc = mi.load_file(str(path), **scene_defaults(path))
    return lambda spp, seed: np.array(mi.render(sc, spp=spp, seed=seed))


def reference(name: str, path: Path, spp: int, threads: int) -> np.ndarray:
    """Mitsuba 3 at ``spp``, cached by the scene text and spp."""
    import mitsuba as mi
    from rdsl.runtime.render.image import read_exr, write_exr

    key = hashlib.sha256(path.read_bytes() + f"{spp}{mi.variant()}".encode()).hexdigest()[:12]
    file = OUT / "ref" / f"{name}_{key}.exr"
    if file.is_file():
        return read_exr(file)[..., :3]
    t = time.perf_counter()
    img = mitsuba_render_fn(path, threads)(spp, 4242)[..., :3]
    print(f"  reference {name}: Mitsuba at {spp} spp, {time.perf_counter() - t:.1f} s",
          flush=True)
    file.parent.mkdir(parents=True, exist_ok=True)
    write_exr(file, img.astype(np.float32))
    return img


def measure(name: str, path: Path, args: argparse.Namespace) -> dict:
    import rdsl

    ref = reference(name, path, args.ref_spp, args.threads)
    s = rdsl.load_scene(path, variant="rgb", **scene_defaults(path))
    t = time.perf_counter()
    s.compile()
    compile_s = time.perf_counter() - t
    mi_fn = mitsuba_render_fn(path, args.threads)
    fns = {"rdsl": lambda seed: s.render(spp=args.spp, seed=seed, threads=args.threads),
           "mitsuba": lambda seed: mi_fn(args.spp, seed)}
    runs: dict[str, list[float]] = {}
    images: dict[str, list[np.ndarray]] = {}
    res = interleaved_medians(fns, args.repeat, runs, images)
    (tr, cr, _), (tm, cm, _) = res["rdsl"], res["mitsuba"]
    pairs = [a / b for a, b in zip(runs["rdsl"], runs["mitsuba"])]
    er, em = (math.sqrt(statistics.fmean(rmse(i, ref) ** 2 for i in images[who]))
              for who in ("rdsl", "mitsuba"))
    return {"scene": name, "rdsl_s": tr, "mitsuba_s": tm, "rdsl_rmse": er, "mitsuba_rmse": em,
            "time_ratio": tr / tm, "equal_error": tr * er * er / (tm * em * em),
            "cpu_ratio": cr / cm, "pair_min": min(pairs), "pair_max": max(pairs),
            "compile_s": compile_s,
            "cached": s.from_cache}


def _timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU seconds (user + system, all threads) of a command."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime


def cold_ttfp(path: Path, threads: int, variant: str) -> dict[str, float]:
    """Wall and CPU seconds of a cold ``rdsl render --spp 1`` (empty cache), of the same
    with only the parsed-source cache kept (a new scene of a user who rendered before: the
    stdlib is parsed, no kernel is cached), and of a cold Mitsuba 3 first render; then the
    wall seconds of both on an edited copy (:func:`edited_copy`), their caches kept."""
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        env = dict(os.environ, RDSL_CACHE_DIR=str(cache))
        d = [f"-Dres={v}" for v in scene_defaults(path).values()]
        cmd = [sys.executable, "-m", "rdsl.cli", "render", str(path), "--spp", "1", "--quiet",
               "--threads", str(threads), "-o", str(Path(tmp) / "a.exr"), *d]
        tr, cr = _timed(cmd, env)
        _background_builds()
        for entry in cache.iterdir():
            if entry.name != "ast":
                shutil.rmtree(entry)
        tn, cn = _timed(cmd, env)
        tb = _background_builds()
        edited = edited_copy(path, Path(tmp) / "edit")
        te, _ = _timed([*cmd[:4], str(edited), *cmd[5:]], env)
        _background_builds()
        kw = ", ".join(f"{k}={v}" for k, v in scene_defaults(path).items())

        def mitsuba(scene: Path) -> list[str]:
            return [sys.executable, "-c",
                    f"import mitsuba as mi, drjit as dr; mi.set_variant('{variant}')\n"
                    + (f"dr.set_thread_count({threads})\n" if "llvm" in variant else "")
                    + f"s = mi.load_file({str(scene)!r}{', ' + kw if kw else ''})\n"
                    "import numpy as np; np.array(mi.render(s, spp=1))\n"]

        env = dict(os.environ, HOME=tmp)  # Dr.Jit's kernel cache lives in ~/.drjit
        tm, cm = _timed(mitsuba(path), env)
        tme, _ = _timed(mitsuba(edited), env)
    return {"ttfp_rdsl": tr, "ttfp_mitsuba": tm, "ttfp_cpu_rdsl": cr, "ttfp_cpu_mitsuba": cm,
            "ttfp_new_rdsl": tn, "ttfp_new_cpu_rdsl": cn, "ttfp_edit_rdsl": te,
            "ttfp_edit_mitsuba": tme, "ttfp_background_s": tb}


def _background_builds(limit: float = 300.0) -> float:
    """Wait for the kernel builds that rdsl runs in the background (runtime/render/
    tier_up.py: a new structure's generic kernels, built beside its first render and going
    on after the command ends) to end; the seconds waited."""
    t = time.perf_counter()
    while time.perf_counter() - t < limit and subprocess.run(
            ["pgrep", "-f", "rdsl.runtime.render.tier_up"], capture_output=True).returncode == 0:
        time.sleep(0.05)
    return time.perf_counter() - t


def edited_copy(path: Path, folder: Path) -> Path:
    """``path`` with the last ``<rgb ... value="r, g, b"/>`` of its BSDFs (a material's
    colour, which the specialized build folds) times 0.9, written into ``folder`` beside
    links to the other files of its folder (meshes, textures)."""
    import re

    text = path.read_text()
    m = [m for b in re.finditer(r"<bsdf\b.*?</bsdf>", text, re.S)
         for m in re.finditer(r'(<rgb\b[^>]*\bvalue=")([^"]+)(")', text[:b.end()])
         if m.start() >= b.start()][-1]
    value = ", ".join(f"{0.9 * float(v):.6g}" for v in m[2].replace(",", " ").split())
    folder.mkdir()
    for f in path.parent.iterdir():
        if f.name != path.name:
            (folder / f.name).symlink_to(f)
    (folder / path.name).write_text(text[:m.start(2)] + value + text[m.end(2):])
    return folder / path.name


def geomean(xs: list[float]) -> float:
    return math.exp(statistics.fmean(math.log(x) for x in xs))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--ttfp", action="store_true", help="also the cold time to first pixel")
    ap.add_argument("--ttfp-only", action="store_true", help="only the time to first pixel")
    ap.add_argument("--json", type=Path, default=OUT / "run.json")
    args = ap.parse_args()
    scenes = all_scenes()
    names = args.names or list(scenes)
    variant = mitsuba_variant()
    print(f"Mitsuba 3 {variant}; {args.spp} spp, median of {args.repeat} alternated runs, "
          f"{args.threads} threads; RMSE against Mitsuba at {args.ref_spp} spp", flush=True)
    print(f"{'scene':<26} {'rdsl s':>7} {'mi s':>7} {'time':>6} {'eq-err':>6} {'cpu':>5} "
          f"{'pairs':>11} {'rmse rdsl':>9} {'rmse mi':>9}")
    if args.ttfp or args.ttfp_only:  # as pip does for an installed package
        import compileall

        compileall.compile_dir(str(ROOT), quiet=1, workers=1)
    rows = []
    for name in names:
        r = {"scene": name} if args.ttfp_only else measure(name, scenes[name], args)
        if args.ttfp or args.ttfp_only:
            r.update(cold_ttfp(scenes[name], args.threads, variant))
        rows.append(r)
        print(_line(r), flush=True)
    _summary(rows)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"variant": variant, "spp": args.spp, "rows": rows},
                                    indent=1))


def _line(r: dict) -> str:
    line = f"{r['scene']:<26}"
    if "rdsl_s" in r:
        line += (f" {r['rdsl_s']:7.3f} {r['mitsuba_s']:7.3f} {r['time_ratio']:6.2f} "
                 f"{r['equal_error']:6.2f} {r['cpu_ratio']:5.2f} "
                 f"{r['pair_min']:5.2f}-{r['pair_max']:<5.2f} "
                 f"{r['rdsl_rmse']:9.5f} {r['mitsuba_rmse']:9.5f}")
    if "ttfp_rdsl" in r:
        line += (f"  ttfp {r['ttfp_rdsl']:.2f} s (new scene {r['ttfp_new_rdsl']:.2f} s) vs "
                 f"{r['ttfp_mitsuba']:.2f} s; edited {r['ttfp_edit_rdsl']:.2f} s vs "
                 f"{r['ttfp_edit_mitsuba']:.2f} s (background build "
                 f"{r.get('ttfp_background_s', 0):.1f} s after); cpu {r['ttfp_cpu_rdsl']:.2f} s "
                 f"({r['ttfp_new_cpu_rdsl']:.2f} s) vs {r['ttfp_cpu_mitsuba']:.2f} s")
    return line


def _summary(rows: list[dict]) -> None:
    if "rdsl_s" in rows[0]:
        print(f"{'geometric mean':<26} {'':>7} {'':>7} "
              f"{geomean([r['time_ratio'] for r in rows]):6.2f} "
              f"{geomean([r['equal_error'] for r in rows]):6.2f}")
    if "ttfp_rdsl" in rows[0]:
        ratio = {k: geomean([r[f"ttfp_{k}rdsl"] / r["ttfp_mitsuba"] for r in rows])
                 for k in ("", "new_")}
        cpu = {k: geomean([r[f"ttfp_{k}rdsl"] / r["ttfp_cpu_mitsuba"] for r in rows])
               for k in ("cpu_", "new_cpu_")}
        edit = geomean([r["ttfp_edit_rdsl"] / r["ttfp_edit_mitsuba"] for r in rows])
        print(f"time to first pixel, rdsl / Mitsuba (geometric mean): cold {ratio['']:.2f} "
              f"(cpu {cpu['cpu_']:.2f}), new scene {ratio['new_']:.2f} "
              f"(cpu {cpu['new_cpu_']:.2f}), edited scene {edit:.2f}")
    print("time = rdsl s / Mitsuba s at the same spp; eq-err = ratio of times to equal RMSE; "
          "cpu = ratio of CPU seconds; pairs = the lowest and highest ratio of one rdsl run to "
          "the Mitsuba run beside it (the noise); ttfp: a whole `rdsl render --spp 1` with an "
          "empty cache (new scene: only the parsed stdlib cached; edited: one colour changed, "
          "the caches kept) against a fresh Python process's Mitsuba 3 first render with an "
          "empty Dr.Jit cache (edited: its cache kept)")


if __name__ == "__main__":
    main()
