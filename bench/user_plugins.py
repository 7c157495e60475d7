"""User plugins cost what stdlib ones cost: the Cornell box with its three colours as

* the stdlib `diffuse`;
* `mydiffuse`, a copy of stdlib/bsdf/diffuse.rdsl under another name, found next to the scene
  (issue 15: it must cost the same, within noise);
* `mypath`, a copy of the stdlib `path` integrator (stdlib/integrator/path.rdsl) under
  another name: a user integrator must cost what the stdlib one does;
* the example Oren–Nayar BSDF (examples/plugins/orennayar.rdsl, sigma 20 degrees), a user
  plugin with some trigonometry, against stdlib BSDFs of similar or greater complexity
  (`plastic`, `roughconductor`): it must render within 10% of them.

    python bench/user_plugins.py [--spp 32] [--res 128] [--repeat 7] [--threads 2]

The scenes are written to a temporary folder; kernels are compiled (or loaded from the cache)
before timing; the variants take turns run by run and the table shows medians of the render
time and the ratio to the stdlib `diffuse`.
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

import rdsl

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT.parent / "shared" / "scenes" / "cbox" / "cbox.xml"
STDLIB = ROOT / "stdlib"
ORENNAYAR = ROOT / "examples" / "plugins" / "orennayar.rdsl"

# name -> (bsdf element for a colour, extra parameters)
CASES = {
    "diffuse (stdlib)": ("diffuse", "reflectance", ""),
    "mydiffuse (user copy)": ("mydiffuse", "reflectance", ""),
    "diffuse, mypath (user integrator)": ("diffuse", "reflectance", ""),
    "orennayar (user)": ("orennayar", "reflectance", '<float name="sigma" value="20"/>'),
    "plastic (stdlib)": ("plastic", "diffuse_reflectance", ""),
    "roughconductor (stdlib)": ("roughconductor", "specular_reflectance",
                                '<float name="alpha" value="0.3"/>'),
}


def write_scenes(folder: Path) -> dict[str, Path]:
    """One copy of the Cornell box per case, the user plugins beside it."""
    src = CBOX.read_text()
    (folder / "mydiffuse.rdsl").write_text(
        re.sub(r"\bbsdf\s+diffuse\b", "bsdf mydiffuse",
               (STDLIB / "bsdf" / "diffuse.rdsl").read_text()))
    (folder / "orennayar.rdsl").write_text(ORENNAYAR.read_text())
    (folder / "mypath.rdsl").write_text(
        re.sub(r"\bintegrator\s+path\b", "integrator mypath",
               (STDLIB / "integrator" / "path.rdsl").read_text()))
    out = {}
    for k, (name, (plugin, param, extra)) in enumerate(CASES.items()):
        text = re.sub(r'<bsdf type="diffuse" id="(\w+)">\s*<rgb name="reflectance"',
                      lambda m, p=plugin, q=param, e=extra:
                      f'<bsdf type="{p}" id="{m.group(1)}">{e}<rgb name="{q}"', src)
        if "mypath" in name:
            text = text.replace('<integrator type="path">', '<integrator type="mypath">')
        path = folder / f"case{k}.xml"
        path.write_text(text)
        out[name] = path
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--target", default="host")
    args = ap.parse_args()
    if not CBOX.is_file():
        raise SystemExit(f"{CBOX}: the shared scenes are not next to this checkout")
    with tempfile.TemporaryDirectory() as tmp:
        scenes = {name: rdsl.load_scene(path, target=args.target, res=args.res)
                  for name, path in write_scenes(Path(tmp)).items()}
        for s in scenes.values():
            s.compile()
            s.render(spp=2, threads=args.threads)  # warm up: pages, thread pool
        times: dict[str, list[float]] = {name: [] for name in scenes}
        for _ in range(args.repeat):
            for name, s in scenes.items():  # take turns: load changes hit every case alike
                t = time.perf_counter()
                s.render(spp=args.spp, seed=1, threads=args.threads)
                times[name].append(time.perf_counter() - t)
    base = statistics.median(times["diffuse (stdlib)"])
    print(f"Cornell box {args.res}x{args.res}, {args.spp} spp, {args.threads} threads, "
          f"median of {args.repeat} alternating runs")
    print(f"{'case (BSDF of the colours, integrator)':36s} {'seconds':>8s} {'vs diffuse':>10s}")
    for name, ts in times.items():
        m = statistics.median(ts)
        print(f"{name:36s} {m:8.3f} {m / base:10.3f}")


if __name__ == "__main__":
    main()
