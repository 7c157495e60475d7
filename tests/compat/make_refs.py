"""Render the compat suite's references with Mitsuba 3 (run once; the EXRs are committed):

    DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1 \\
        python tests/compat/make_refs.py [SHEET ...] [--assets]

Each sheet of tests/compat/cases.py is rendered at REF_SPP (``llvm_ad_*`` where libLLVM is
present, else ``scalar_*``) into refs/SHEET.exr, and Mitsuba's own per-tile RMSE at the
test's spp (the median over three seeds, scalar variant) goes to refs/noise.json: the noise
level rdsl is compared with where the ``mitsuba`` package is not installed.  ``--assets``
writes tests/compat/assets/ first."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _sheet as S
import numpy as np
from _suite import SHEETS

NOISE = S.REFS / "noise.json"
SEEDS = (11, 12, 13)


def mitsuba_noise(path: Path, sh: S.Sheet, ref: np.ndarray) -> dict[str, float]:
    imgs = [sh.pick(S.mitsuba_render(path, S.mitsuba_variant(sh.variant, True), sh.spp, s))
            for s in SEEDS]
    return {c.name: float(np.median([S.rmse(sh.tile(m, i), sh.tile(ref, i)) for m in imgs]))
            for i, c in enumerate(sh.cases)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sheets", nargs="*", help="sheet names (default: all)")
    ap.add_argument("--assets", action="store_true", help="write the assets first")
    args = ap.parse_args()
    if args.assets:
        from _assets import write_all
        write_all(S.ASSETS)
    from rdsl.runtime.render.image import write_exr

    S.REFS.mkdir(exist_ok=True)
    noise = json.loads(NOISE.read_text()) if NOISE.is_file() else {}
    chosen = [s for s in SHEETS if not args.sheets or s.name in args.sheets]
    for sh in chosen:
        t0 = time.time()
        with tempfile.TemporaryDirectory() as tmp:
            path = S.write(sh, Path(tmp))
            ref = sh.pick(S.mitsuba_render(path, S.mitsuba_variant(sh.variant, False),
                                           S.REF_SPP, 1))
            write_exr(S.ref_path(sh), ref.astype(np.float32))
            noise[sh.name] = {"spp": sh.spp, "ref_spp": S.REF_SPP,
                              "rmse": mitsuba_noise(path, sh, ref)}
        print(f"{sh.name}: {time.time() - t0:.1f} s", flush=True)
        NOISE.write_text(json.dumps(noise, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
