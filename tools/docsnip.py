"""Try rdsl on scene snippets (for instance the XML examples of Mitsuba 3's plugin docs).

Reads ``KIND__PLUGIN__N.xml`` snippets from a folder given as an argument (nothing is
fetched and no snippet text lives here), wraps each in a small complete scene (a BSDF on a
sphere, a texture as a diffuse reflectance, an emitter in a small stage, a sensor, film,
filter, sampler or integrator in place of the default one, a spectrum as a light's
radiance), writes the data files the snippet names (bitmaps, meshes, spectra) as small
generated files, renders the scene with rdsl (``rdsl render`` and ``rdsl.load_scene``) and
with Mitsuba 3 (a scalar variant), and classifies the outcome:

- ``match``: both render and agree within noise (block means, against Mitsuba's own
  seed-to-seed difference);
- ``differs``: both render and the images disagree;
- ``unsupported``: rdsl refuses with a clear error naming a plugin it lacks;
- ``error``: rdsl refuses with another error (valid or not, see ``mitsuba``);
- ``traceback``: rdsl ends in a Python traceback;
- ``both-reject``: rdsl and Mitsuba both refuse it (rdsl with a clear error);
- ``ok-mitsuba-rejects``: rdsl renders what Mitsuba refuses.

    python tools/docsnip.py SNIPPET_DIR OUT_DIR [--spp 64] [--res 48] [--only GLOB]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import re
import subprocess
import sys
import traceback
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from docsnip_scene import POLARIZED, build_scene, write_assets  # noqa: E402


def variant_of(kind: str, plugin: str) -> str:
    if plugin in POLARIZED:
        return "spectral_polarized"
    return "spectral" if kind == "spectrum" else "rgb"


def rgb3(img: np.ndarray) -> np.ndarray:
    """An image as (H, W, 3): a one-channel (luminance) film repeated, extra channels cut."""
    img = np.asarray(img, np.float64)
    img = img[..., None] if img.ndim == 2 else img
    return np.repeat(img[..., :1], 3, -1) if img.shape[-1] < 3 else img[..., :3]


def block_error(a: np.ndarray, b: np.ndarray, k: int = 8) -> float:
    """Largest difference of k x k block means, relative to ``b``'s (plus 0.05)."""
    k = max(1, min(k, a.shape[0], a.shape[1]))
    h, w = (a.shape[0] // k) * k, (a.shape[1] // k) * k

    def blocks(x: np.ndarray) -> np.ndarray:
        x = x[:h, :w, :3]
        return x.reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))
    return float((np.abs(blocks(a) - blocks(b)) / (0.05 + np.abs(blocks(b)))).max())


def render_mitsuba(path: Path, variant: str, spp: int) -> tuple[list, str]:
    import mitsuba as mi
    try:
        mi.set_variant(f"scalar_{variant}")
        scene = mi.load_file(str(path))
        imgs = [rgb3(mi.render(scene, spp=spp, seed=s)) for s in (1, 2)]
        return imgs, ""
    except Exception as e:  # noqa: BLE001 - any refusal is an outcome
        return [], str(e).strip().splitlines()[-1][:200] if str(e).strip() else repr(e)


def render_rdsl_api(path: Path, variant: str, spp: int):
    import rdsl
    from rdsl.compiler.diagnostics import CompileError
    try:
        img = rdsl.load_scene(path, variant=variant).render(spp=spp, seed=3)
        return rgb3(img), "", ""
    except CompileError as e:
        return None, "error", str(e).strip()
    except Exception:  # noqa: BLE001 - a traceback is what this counts
        return None, "traceback", traceback.format_exc(limit=3)


def render_rdsl_cli(path: Path, variant: str, out: Path) -> tuple[int, str]:
    r = subprocess.run([sys.executable, "-m", "rdsl.cli", "render", str(path), "--spp", "4",
                        "--variant", variant, "--quiet", "-o", str(out)],
                       capture_output=True, text=True, timeout=900)
    return r.returncode, (r.stderr + r.stdout).strip()


def classify(snip: Path, out_root: Path, spp: int, res: int) -> dict:
    kind, plugin = snip.stem.split("__")[:2]
    variant = variant_of(kind, plugin)
    folder = out_root / snip.stem
    folder.mkdir(parents=True, exist_ok=True)
    text = snip.read_text()
    write_assets(text, folder)
    scene = folder / "scene.xml"
    scene.write_text(build_scene(kind, text, res))
    row = {"snippet": snip.stem, "variant": variant}
    rc, cli_msg = render_rdsl_cli(scene, variant, folder / "cli.exr")
    ours, err_kind, api_msg = render_rdsl_api(scene, variant, spp)
    theirs, mi_msg = render_mitsuba(scene, variant, spp)
    msg = api_msg or cli_msg
    if "Traceback" in cli_msg or err_kind == "traceback":
        cls = "traceback"
    elif (ours is None or rc != 0) and not theirs:
        cls = "both-reject"
    elif ours is None or rc != 0:
        lowered = msg.lower()
        cls = "unsupported" if re.search(r"(no|unknown|unsupported|lacks).{0,40}plugin|"
                                          r"plugin.{0,60}(not found|found nowhere)",
                                          lowered) else "error"
    elif not theirs:
        cls = "ok-mitsuba-rejects"
    elif ours.shape != theirs[0].shape:
        cls = "differs"
        row["shape"] = f"rdsl {ours.shape}, Mitsuba {theirs[0].shape}"
    else:
        e_ours = block_error(ours, theirs[0])
        e_noise = block_error(theirs[1], theirs[0])
        row.update(err=round(e_ours, 3), noise=round(e_noise, 3),
                   mean_ours=round(float(ours.mean()), 4),
                   mean_mi=round(float(theirs[0].mean()), 4))
        cls = "match" if e_ours <= 2.0 * e_noise + 0.03 else "differs"
    if mi_msg and cls != "ok-mitsuba-rejects":
        row["mitsuba"] = mi_msg
    row["class"] = cls
    if msg and cls in ("traceback", "error", "unsupported"):
        row["message"] = msg.splitlines()[-1][:240] if cls == "traceback" else msg[:240]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("snippets", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--res", type=int, default=48)
    ap.add_argument("--only", default="*", help="comma-separated globs of snippet names")
    args = ap.parse_args()
    rows = []
    for snip in sorted(args.snippets.glob("*.xml")):
        if not any(fnmatch.fnmatch(snip.stem, g) for g in args.only.split(",")):
            continue
        row = classify(snip, args.out, args.spp, args.res)
        rows.append(row)
        print(json.dumps(row), flush=True)
    counts: dict[str, int] = {}
    for r in rows:
        counts[r["class"]] = counts.get(r["class"], 0) + 1
    print("\n| class | count |\n|---|---|")
    for k, v in sorted(counts.items()):
        print(f"| {k} | {v} |")
    (args.out / "table.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
