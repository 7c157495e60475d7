"""Time to first pixel of two rdsl checkouts, alternated: the whole cold ``rdsl render --spp 1``
(empty cache) of each scene, run by run, wall and CPU seconds (medians).

    python bench/ttfp_before_after.py BASE_PKG_PARENT [NAME ...] [--repeat 2]

BASE_PKG_PARENT is a folder holding ``rdsl`` (a link to the other checkout), put first on
PYTHONPATH for the "before" runs, e.g.::

    git worktree add --detach /tmp/base main && mkdir /tmp/basepkg && \\
        ln -s /tmp/base /tmp/basepkg/rdsl
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from scene_set import _background_builds, _timed, all_scenes, scene_defaults


def cold(path: Path, pythonpath: str | None) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, RDSL_CACHE_DIR=str(Path(tmp) / "cache"))
        if pythonpath:
            env["PYTHONPATH"] = pythonpath
        d = [f"-Dres={v}" for v in scene_defaults(path).values()]
        timed = _timed([sys.executable, "-m", "rdsl.cli", "render", str(path), "--spp", "1",
                        "--quiet", "-o", str(Path(tmp) / "a.exr"), *d], env)
        # the generic build a new structure starts after its first image goes on after the
        # command: it must neither load the next run nor write into a folder being removed
        _background_builds()
        return timed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base", type=Path)
    ap.add_argument("names", nargs="*")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    scenes = all_scenes()
    print(f"{'scene':<26} {'before s':>9} {'after s':>8} {'ratio':>6} | {'before cpu':>10} "
          f"{'after cpu':>9} {'ratio':>6}")
    for name in args.names or list(scenes):
        runs: dict[str, list[tuple[float, float]]] = {"before": [], "after": []}
        for _ in range(args.repeat):
            runs["before"].append(cold(scenes[name], str(args.base)))
            runs["after"].append(cold(scenes[name], None))
        (wb, cb), (wa, ca) = ([statistics.median(x[i] for x in runs[k]) for i in (0, 1)]
                              for k in ("before", "after"))
        print(f"{name:<26} {wb:9.2f} {wa:8.2f} {wa / wb:6.2f} | {cb:10.2f} {ca:9.2f} "
              f"{ca / cb:6.2f}", flush=True)


if __name__ == "__main__":
    main()
