"""The quick tier of kernels (LLVM O0, for small renders whose kernels are not cached): the
same image, bit for bit, as the full tier, and chosen only where it pays."""

from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.runtime.render.renderer import QUICK_SAMPLES

CBOX = Path(__file__).resolve().parents[1] / "examples" / "cbox" / "cbox.xml"


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))


def test_quick_tier_renders_the_full_tiers_image(fresh_cache):
    quick = rdsl.load_scene(CBOX, res=24)
    img_quick = quick.render(spp=2, seed=5, threads=2)  # small and not cached: quick tier
    assert quick.compile(quick=True).quick and not quick.from_cache
    full = rdsl.load_scene(CBOX, res=24)
    assert not full.compile().quick  # asked without quick: the full tier (LLVM O3)
    img_full = full.render(spp=2, seed=5, threads=2)
    assert np.array_equal(img_quick, img_full)  # no fast-math in either: same arithmetic
    assert img_full.std() > 0


def test_cached_full_tier_is_preferred(fresh_cache):
    rdsl.load_scene(CBOX, res=24).compile()  # the full tier lands in the cache
    again = rdsl.load_scene(CBOX, res=24)
    again.render(spp=1, seed=0, threads=2)
    mod = again.compile(quick=True)
    assert not mod.quick and again.from_cache


def test_large_renders_take_the_full_tier():
    scene = rdsl.load_scene(CBOX, res=64)
    pixels = 64 * 64
    assert scene.quick_fits(QUICK_SAMPLES // pixels)
    assert not scene.quick_fits(QUICK_SAMPLES // pixels + 1)
