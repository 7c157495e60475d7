"""The quick tier of kernels (LLVM O0, for small renders whose kernels are not cached): the
same image, bit for bit, as the full tier, chosen only where it pays, and replaced by the
full tier (built in the background) when a scene is rendered again and again."""

import time
from pathlib import Path

import numpy as np
import pytest
import rdsl
from rdsl.compiler.build import Build
from rdsl.runtime.render.renderer import QUICK_SAMPLES
from rdsl.runtime.render.tier_up import RENDERS_BEFORE_TIER_UP, TierUp

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


def _render_until_full(scene, seconds: float = 240.0) -> int:
    """Render (small, so quick-tier kernels) until the scene runs the full tier; the
    number of renders it took (runtime/render/tier_up.py)."""
    t0, n = time.monotonic(), 0
    while scene.compile(quick=True).quick:
        assert time.monotonic() - t0 < seconds, "the full tier never replaced the quick one"
        scene.render(spp=1, seed=0, threads=2)
        n += 1
        time.sleep(0.05)
    return n


def test_a_loop_of_small_renders_switches_to_the_full_tier(fresh_cache):
    scene = rdsl.load_scene(CBOX, res=24)
    first = scene.render(spp=2, seed=5, threads=2)
    assert scene.compile(quick=True).quick and scene._tier_up is None  # one render: no build
    renders = _render_until_full(scene)
    assert renders >= RENDERS_BEFORE_TIER_UP - 1
    assert np.array_equal(scene.render(spp=2, seed=5, threads=2), first)  # bit for bit
    again = rdsl.load_scene(CBOX, res=24)  # the background build filled the cache
    assert not again.compile(quick=True).quick and again.from_cache


def test_a_stale_background_build_is_stopped(fresh_cache, tmp_path):
    scene = rdsl.load_scene(CBOX, res=24)
    for _ in range(RENDERS_BEFORE_TIER_UP):
        scene.render(spp=1, seed=0, threads=2)
    job = scene._tier_up
    assert job is not None and not job.done()
    scene.params["red.reflectance.value"] = np.array([0.2, 0.3, 0.4], np.float32)
    assert scene._tier_up is None and job.proc.returncode is not None  # stopped
    assert not [p for p in (tmp_path / "cache").iterdir() if p.name.startswith(".")]
    img = scene.render(spp=1, seed=0, threads=2)  # the new (generic) kernels
    assert img.std() > 0


def test_a_failed_background_build_keeps_the_quick_tier(fresh_cache):
    job = TierUp("fn broken( -> Float {", {"build": Build.of("host", "rgb")})
    while not job.done():
        time.sleep(0.05)
    with pytest.warns(UserWarning, match="background build of the full-tier kernels failed"):
        assert job.load() is None
    assert "CompileError" in job.failure and "1:" in job.failure


def test_a_loop_of_backward_passes_switches_to_the_full_tier(fresh_cache):
    """``scene.backward`` tiers like a render: a small pass not cached yet runs the quick
    adjoint kernel, a loop of them the full tier once built, the same gradient bit for bit."""
    scene = rdsl.load_scene(CBOX, res=16)
    img = scene.render(spp=1, seed=0, threads=2)
    d_img, key = np.ones_like(img) / img.size, "red.reflectance.value"
    first = scene.backward(d_img, [key], spp=1, seed=3, threads=2)[key]
    (twin,) = [v for k, v in vars(scene).items() if k.startswith("_reverse_")]
    assert twin._module.quick and np.all(first != 0)
    t0 = time.monotonic()
    while twin._module.quick:
        assert time.monotonic() - t0 < 240, "the full tier never replaced the quick one"
        time.sleep(0.05)
        grad = scene.backward(d_img, [key], spp=1, seed=3, threads=2)[key]
    assert np.array_equal(grad, first)
