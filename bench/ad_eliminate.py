"""Graph elimination (compiler/passes/eliminate.py): what the reverse sweeps keep of their
forward parts, with and without it, and the time and peak RSS of ``scene.backward`` for
the two cases of the paper's Table 2: colour parameters (the albedos of two walls and the
light's radiance) and a texture (the 64x64 bitmap on the back wall of
examples/inverse/texture.py, its 12288 texel values); and a third, the roughness of a rough
conductor (GGX, alpha 0.2) on the green wall.

"Tape bytes per lane per bounce" = 4 x the number of distinct non-constant values that the
sweep of one iteration of the bounce loop's adjoint reads from that iteration's forward
part (8 for a 64-bit integer), counted on the IR after ``eliminate`` and DCE
(compiler/passes/ad_tape.py); per call for a kernel's own body.  Peak RSS is that of a
fresh process that loads the Cornell box and runs one ``backward`` (the adjoint kernel
compiled, or loaded from the cache, in it); times are medians of alternated runs.  The tape
table also has the Cornell box with a rough conductor for the green wall (GGX, alpha 0.2),
where elimination has more to do than on diffuse walls.  Not a test: run it by hand.

    python bench/ad_eliminate.py [--res 64] [--spp 16] [--repeat 3] [--threshold 10]
                                 [--cases albedo texture]
"""

from __future__ import annotations

import argparse
import io
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / "examples" / "cbox" / "cbox.xml"
NAMES = ["red.reflectance.value", "green.reflectance.value", "light.emitter.radiance.value"]
TEXELS = "wall_texture.data"  # examples/inverse/texture.py's
CASES = ("albedo", "texture", "roughness")
BSDFS = [("diffuse", "eval"), ("roughconductor", "eval"), ("roughplastic", "eval"),
         ("principled", "eval"), ("roughdielectric", "sample")]


def tapes(module_fn, build) -> list:
    """The tape of each sweep of the function ``module_fn()`` compiles for ``build``."""
    from rdsl.compiler.driver import pipeline, run_passes
    from rdsl.compiler.passes.ad_tape import tape

    module, name, spec = module_fn()
    stop = "eliminate" if build.eliminate else "ad_reverse"
    run_passes(module, pipeline(build, spec), out=io.StringIO(), stop_after=stop)
    return tape(module.functions[name])


def cbox_module(scene):
    from rdsl.compiler.driver import frontend
    from rdsl.compiler.passes.specialize import parameter_slots

    spec = parameter_slots(scene.scene_spec, scene.build.model)[0]
    return lambda: (frontend(scene.kernel_src, "cbox.rdsl", scene.search_paths),
                    "render_sample", spec)


def tape_table(threshold: int) -> None:
    import rdsl
    from rdsl.compiler.build import Build
    from rdsl.compiler.driver import frontend

    print("tape bytes per lane: per iteration of a loop's adjoint (the path tracer's "
          "bounce loop: per bounce), per call of a kernel's own body")
    print(f"{'kernel':<32} {'sweep':<10} {'bytes/lane, off':>16} {'eliminate':>10} "
          f"{'ratio':>6}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        scenes = [("cbox", CBOX), ("cbox, rough wall", rough_cbox(Path(tmp)))]
        for (label, path), depth in [(s, d) for s in scenes for d in (3, -1)]:
            scene = rdsl.load_scene(path, res=16, max_depth=depth)
            scene.use_generic()
            scene.compile()
            rows.append((f"{label} render_sample d={depth}", cbox_module(scene)))
    for name, fn in BSDFS:
        path = ROOT / "stdlib" / "bsdf" / f"{name}.rdsl"
        rows.append((f"{name}.{fn}", lambda p=path, n=f"{name}.{fn}": (frontend(p), n, None)))
    for label, make in rows:
        off = tapes(make, Build.of("host", "rgb", ad="reverse"))
        on = tapes(make, Build.of("host", "rgb", ad="reverse", eliminate=threshold))
        for a, b in zip(off, on):
            what = f"loop@{a.line}" if a.kind == "loop" else "per call"
            print(f"{label:<32} {what:<10} {a.bytes:>16} {b.bytes:>10} "
                  f"{b.bytes / max(a.bytes, 1):>6.2f}")


def rough_cbox(folder: Path) -> Path:
    """The Cornell box with a rough conductor (GGX, alpha 0.2) for the green wall."""
    xml = CBOX.read_text().replace(
        '<bsdf type="diffuse" id="green">\n        <rgb name="reflectance" '
        'value="0.105421, 0.37798, 0.076425"/>',
        '<bsdf type="roughconductor" id="green"><string name="distribution" value="ggx"/>'
        '<float name="alpha" value="0.2"/>')
    assert "roughconductor" in xml, "the green wall of examples/cbox/cbox.xml changed"
    (folder / "cbox_rough.xml").write_text(xml)
    return folder / "cbox_rough.xml"


def case_scene(case: str, res: int, depth: int, folder: Path):
    """The scene and the parameters ``backward`` differentiates in ``case``."""
    import rdsl

    if case == "albedo":
        return rdsl.load_scene(CBOX, res=res, max_depth=depth), NAMES
    if case == "roughness":
        return rdsl.load_scene(rough_cbox(folder), res=res, max_depth=depth), \
            ["green.alpha.value"]
    sys.path.insert(0, str(ROOT / "examples" / "inverse"))
    from texture import textured_cbox

    return rdsl.load_scene(textured_cbox(folder), res=res, max_depth=depth), [TEXELS]


def peak_rss_mib() -> float:
    """This process's peak RSS (VmHWM: getrusage's ru_maxrss would include the parent's
    peak, which survives the exec of a child on Linux)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(args) -> None:
    """One backward in this process: prints its times and peak RSS as JSON."""
    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        scene, names = case_scene(args.case, args.res, args.depth, Path(tmp))
        d = np.random.default_rng(0).standard_normal((args.res, args.res, 3))
        el = args.threshold if args.on else False
        t = time.perf_counter()
        g = scene.backward(d, names, spp=args.spp, seed=1, eliminate=el)
        first = time.perf_counter() - t
        times = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            scene.backward(d, names, spp=args.spp, seed=1, eliminate=el)
            times.append(time.perf_counter() - t)
    rss = peak_rss_mib()
    print(json.dumps({"first": first, "median": statistics.median(times), "rss": rss,
                      "grad": [float(x) for v in g.values() for x in np.ravel(v)]}))


def run_child(args, case: str, on: bool) -> dict:
    cmd = [sys.executable, __file__, "--child", "--res", str(args.res), "--spp",
           str(args.spp), "--repeat", "1", "--threshold", str(args.threshold),
           "--depth", str(args.depth), "--case", case] + (["--on"] if on else [])
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threshold", type=int, default=10)
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--child", action="store_true")
    ap.add_argument("--on", action="store_true")
    ap.add_argument("--case", default="albedo", choices=CASES)
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    args = ap.parse_args()
    if args.child:
        child(args)
        return 0
    tape_table(args.threshold)
    runs: dict[tuple[str, bool], list[dict]] = {(c, on): [] for c in args.cases
                                                for on in (False, True)}
    for _ in range(args.repeat):  # alternated, each in a fresh process
        for key in runs:
            runs[key].append(run_child(args, *key))
    print(f"\nCornell box {args.res}x{args.res}, {args.spp} spp, max_depth {args.depth}, "
          f"{args.repeat} fresh processes each (the paper's Table 2)")
    print(f"{'case':<8} {'eliminate':<10} {'backward s':>10} {'peak RSS MiB':>13} "
          f"{'max rel. grad difference':>25}")
    for (case, on), r in runs.items():
        a, b = runs[case, False][0]["grad"], r[0]["grad"]
        scale = max(abs(x) for x in a) or 1.0  # texels: many gradients are ~0
        rel = max(abs(x - y) for x, y in zip(a, b)) / scale
        print(f"{case:<8} {'on' if on else 'off':<10} "
              f"{statistics.median(x['median'] for x in r):>10.3f} "
              f"{statistics.median(x['rss'] for x in r):>13.0f} {rel:>25.2e}")
    print("(the gradient difference is relative to the largest gradient of the case)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
