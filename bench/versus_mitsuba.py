"""rdsl against Mitsuba 3 (`scalar_rgb`) on one scene, the noise-aware way: both render at
--spp and are measured against Mitsuba at --ref-spp (tests/_mitsuba_compare.py, which
tests/test_compat_images.py uses).  A ratio near 1 is noise; a bias keeps it high.

    python bench/versus_mitsuba.py SCENE.xml [--spp 32] [--ref-spp 1024] [--seeds 0 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _mitsuba_compare import versus_mitsuba


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    args = ap.parse_args()
    for seed in args.seeds:
        print(f"{args.scene.name} seed {seed}: "
              f"{versus_mitsuba(args.scene, args.spp, args.ref_spp, seed)}")


if __name__ == "__main__":
    main()
