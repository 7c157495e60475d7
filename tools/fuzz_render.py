"""Render mutated scenes: each must render, or fail with a ``CompileError`` naming a file and
a line; anything else (a traceback, a hang, an image with NaN pixels) is printed as a bug.

    python -m rdsl.tools.fuzz_render [--kind values|edits|plugins] [--cases 100] [--seed 1]

``values`` replaces one number of a scene of the repository by an extreme one (0, -1, nan,
inf, 1e30, 2**25, 2**31 - 1...), the kind of edit that loads and then breaks a render;
``edits`` applies tests/test_fuzz_scenes.py's structural mutations (which that test only
loads); ``plugins`` mutates the tokens of examples/plugins' ``.rdsl`` files and renders the
scene beside each.  Renders are 1 spp with the quick tier, one compile each (about 2 s), so a
campaign of 100 cases takes a few minutes; films over a million pixels are skipped.  Each
case lives in its own temporary folder beside links to its source folder's files.  This is
what found the bugs fixed in 9ea2c88 and 6451a51 (docs/renderer.md, step 1)."""

from __future__ import annotations

import argparse
import os
import random
import re
import signal
import sys
import tempfile
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXTREME = ["0", "-1", "1e30", "-1e30", "nan", "inf", "-inf", "33554432", "2147483647",
           "-2147483648", "1e-30", "999", "-0.0", "1e-45", "3.4e38", "100000"]
NUMBER = re.compile(r'\b(?:value|x|y|z|angle)="(-?[0-9.eE+-]+)"')
TOKEN = re.compile(r"[A-Za-z_]\w*|\d+\.\d*|\d+|&&|\|\||[-+*/%<>=!(){}\[\],;:.]")
TOKENS = ["Float", "Int", "Bool", "Vec3", "Spectrum", "0", "1.0", "-1", "x", "(", ")", "{",
          "}", ";", "let", "var", "return", "if", "fn", "param", "eval", "sample", "1e40",
          "true", "wi", "wo", "sqrt", "+", "*", "/", ".", ","]
SECONDS = 120
MAX_PIXELS = 1 << 20


def corpus() -> list[Path]:
    return sorted([*(ROOT / "bench/scenes/set").glob("*.xml"), ROOT / "examples/cbox/cbox.xml",
                   *(ROOT / "bench/scenes/compat").glob("*.xml"),
                   *(ROOT / "examples/plugins").glob("*.xml"), ROOT / "bench/scenes/materials.xml"])


def extreme_value(text: str, rng: random.Random) -> str:
    m = rng.choice(list(NUMBER.finditer(text)))
    return text[:m.start(1)] + rng.choice(EXTREME) + text[m.end(1):]


def edited(text: str, rng: random.Random) -> str:
    sys.path.insert(0, str(ROOT / "tests"))
    from test_fuzz_scenes import mutate

    for _ in range(rng.randrange(1, 3)):
        text = mutate(text, rng)
    return text


def plugin_tokens(text: str, rng: random.Random) -> str:
    for _ in range(rng.randrange(1, 3)):
        m = rng.choice(list(TOKEN.finditer(text)))
        k = rng.randrange(3)
        new = "" if k == 0 else rng.choice(TOKENS) if k == 1 else f"{m[0]} {m[0]}"
        text = text[:m.start()] + new + text[m.end():]
    return text


def case_files(kind: str, rng: random.Random, folder: Path) -> Path:
    """Write one mutated case into ``folder``; returns the scene to render."""
    if kind == "plugins":
        name = rng.choice(["ao", "orennayar", "wood"])
        scene = ROOT / f"examples/plugins/{name}.xml"
        edited_file = scene.with_suffix(".rdsl")
        mutate: Callable[[str, random.Random], str] = plugin_tokens
    else:
        scene = edited_file = rng.choice(corpus())
        mutate = extreme_value if kind == "values" else edited
    for f in scene.parent.iterdir():
        if f.name != edited_file.name:
            (folder / f.name).symlink_to(f)
    (folder / edited_file.name).write_bytes(
        mutate(edited_file.read_text(), rng).encode("utf-8", "replace"))
    return folder / scene.name


def render(path: Path) -> str:
    """``ok``, ``clear`` (an error at a line), or what went wrong."""
    import numpy as np

    from rdsl.compiler.diagnostics import CompileError
    from rdsl.runtime.render.renderer import load_scene

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = load_scene(path)
            film = scene.desc.sensor.film
            if film["width"] * film["height"] > MAX_PIXELS:
                return "ok (film too large to try)"
            img = scene.render(spp=1, seed=1, progress=False)
        return "ok" if np.isfinite(img).all() else "BUG: NaN or infinite pixels"
    except CompileError as e:
        return "clear" if re.search(r"\.(xml|rdsl):\d+", str(e)) else f"BUG (no line): {e}"
    except TimeoutError:
        return f"BUG: no answer within {SECONDS} s"
    except Exception as e:  # noqa: BLE001 - what this tool looks for
        where = traceback.extract_tb(e.__traceback__)[-1]
        return f"BUG: {type(e).__name__}: {e} ({where.filename}:{where.lineno})"


def _alarm(signum, frame):  # noqa: ARG001 - signal handler signature
    raise TimeoutError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kind", choices=["values", "edits", "plugins"], default="values")
    ap.add_argument("--cases", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    os.environ.setdefault("RDSL_QUICK", "1")  # the same images, compiled sooner
    os.environ.setdefault("RDSL_PREBUILD", "0")
    rng = random.Random(args.seed)
    signal.signal(signal.SIGALRM, _alarm)
    counts: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix="rdsl-fuzz-") as tmp:
        for case in range(args.cases):
            folder = Path(tmp) / f"case{case}"
            folder.mkdir()
            path = case_files(args.kind, rng, folder)
            signal.alarm(SECONDS)
            try:
                status = render(path)
            finally:
                signal.alarm(0)
            key = status.split(":")[0].split(" (")[0]
            counts[key] = counts.get(key, 0) + 1
            if status.startswith("BUG"):
                print(f"case {case} ({path.name}): {status}", flush=True)
    print(", ".join(f"{n} {k}" for k, n in sorted(counts.items())))
    return 1 if any(k.startswith("BUG") for k in counts) else 0


if __name__ == "__main__":
    sys.exit(main())
