"""rdsl against Mitsuba 3 on one scene, the noise-aware way: both render at the same spp and
are measured against a high-spp Mitsuba render (the reference, whose own noise is small at
that count); rdsl passes when its RMSE is at most ``ratio`` times Mitsuba's.  A bias shows
as an RMSE that stays high however many samples; noise alone gives about the same RMSE."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest


@dataclass
class Versus:
    """RMSEs against the reference, and the images' channel means."""

    rdsl: float
    mitsuba: float
    means: tuple[np.ndarray, np.ndarray, np.ndarray]  # rdsl, mitsuba, reference

    def __str__(self) -> str:
        return (f"RMSE rdsl {self.rdsl:.5f} mitsuba {self.mitsuba:.5f} "
                f"(ratio {self.rdsl / self.mitsuba:.3f}); means {self.means}")


def mitsuba_render(path: Path, spp: int, seed: int, variant: str = "scalar_rgb"
                   ) -> np.ndarray:
    mi = pytest.importorskip("mitsuba")
    mi.set_variant(variant)
    img = mi.render(mi.load_file(str(path)), spp=spp, seed=seed)
    return np.array(img, np.float64)[..., :3]


def versus_mitsuba(path: Path, spp: int = 32, ref_spp: int = 1024, seed: int = 0) -> Versus:
    """rdsl (rgb) and Mitsuba (scalar_rgb) at ``spp``, against Mitsuba at ``ref_spp``."""
    from rdsl.runtime.render.renderer import load_scene

    ref = mitsuba_render(path, ref_spp, seed=1000 + seed)
    mine = np.asarray(load_scene(path).render(spp=spp, seed=seed), np.float64)[..., :3]
    theirs = mitsuba_render(path, spp, seed=2000 + seed)

    def rmse(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a - ref) ** 2)))

    return Versus(rmse(mine), rmse(theirs),
                  (mine.mean(axis=(0, 1)), theirs.mean(axis=(0, 1)), ref.mean(axis=(0, 1))))
