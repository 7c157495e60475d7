"""The generic build standing in for a small render's specialized kernels
(runtime/render/stand_in.py): a scene of a new structure renders with its own quick kernels
while the generic ones are built in the background; a scene of a structure rendered before
whose own kernels are not cached renders with those generic ones, so that editing a value
compiles nothing; the image is the specialized build's to float rounding; the scene's own
kernels replace the stand-in from its second render on, and a large render compiles them at
once."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from _scenes import CBOX, edited_copy
from rdsl.cli import main
from rdsl.runtime.render import renderer, stand_in
from rdsl.runtime.render.renderer import load_scene
from rdsl.runtime.render.stand_in import is_stand_in
from rdsl.runtime.render.tier_up import RENDERS_BEFORE_TIER_UP

pytestmark = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")

RED = "0.570068, 0.0430135, 0.0443706"  # the red wall's reflectance


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A kernel cache of this test's own, and stand-ins allowed (conftest.py forbids them)."""
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("RDSL_GENERIC_FIRST", "1")
    return tmp_path


def reads_prm(mod) -> bool:
    """Whether ``mod``'s render kernel reads parameters at run time (a generic build)."""
    kernel = next(k for k in mod.manifest["kernels"] if k["name"] == "render_sample")
    return any(p["name"] == "PRM" for p in kernel["params"])


def specialized_image(path, spp=2, seed=5, **defaults):
    """The image of the scene's own (specialized) kernels."""
    s = load_scene(path, **defaults)
    s.compile()  # the full tier, as a large render gets: never a stand-in
    assert not is_stand_in(s._module)
    return s.render(spp=spp, seed=seed)


def first_render(path, spp=2, seed=5, **defaults):
    """Render a scene of a structure not seen before: its own quick kernels render, and the
    generic ones are built beside them (waited for here); the scene and its image."""
    stand_in._building = None
    s = load_scene(path, **defaults)
    img = s.render(spp=spp, seed=seed)
    assert not is_stand_in(s._module) and not reads_prm(s._module)
    job = stand_in._building
    assert job is not None, "the generic kernels are built in the background"
    assert job.proc.wait() == 0
    return s, img


def test_an_edited_value_renders_from_the_cache(cache):
    _, img_a = first_render(CBOX, res=16)
    (cache / "edit").mkdir()
    path = edited_copy(CBOX, cache / "edit", RED, "0.2, 0.6, 0.3")
    b = load_scene(path, res=16)
    img_b = b.render(spp=2, seed=5)
    assert is_stand_in(b._module) and b.from_cache and b.prm.size > 1  # no compile
    np.testing.assert_allclose(img_b, specialized_image(path, res=16), rtol=0, atol=1e-5)
    assert not np.allclose(img_a, img_b, atol=1e-3)  # the edited value did reach the kernel
    # an integrator's depth is a value too
    c = load_scene(CBOX, res=16, max_depth=3)
    c.render(spp=1)
    assert is_stand_in(c._module) and c.from_cache
    # the film's size is in the kernel's text: a new structure
    first_render(CBOX, spp=1, res=24)


def test_the_scenes_own_kernels_replace_the_stand_in(cache):
    first_render(CBOX, res=16)
    (cache / "edit").mkdir()
    s = load_scene(edited_copy(CBOX, cache / "edit", RED, "0.2, 0.6, 0.3"), res=16)
    first = s.render(spp=2, seed=1)
    assert is_stand_in(s._module)
    for _ in range(RENDERS_BEFORE_TIER_UP - 1):
        s.render(spp=2, seed=1)
    job = s._tier_up
    assert job is not None, "the second render starts the specialized build"
    assert job.proc.wait() == 0
    last = s.render(spp=2, seed=1)
    assert not is_stand_in(s._module) and not reads_prm(s._module)
    np.testing.assert_allclose(last, first, rtol=0, atol=1e-5)


def test_one_background_build_at_a_time_and_none_on_one_core(cache, monkeypatch):
    stand_in._building = None
    load_scene(CBOX, res=16).render(spp=1)
    job = stand_in._building
    load_scene(CBOX, res=20).render(spp=1)  # another structure while the first build runs
    assert stand_in._building is job or job.done()
    assert job.proc.wait() == 0
    stand_in._building = None
    monkeypatch.setattr(stand_in.os, "cpu_count", lambda: 1)
    load_scene(CBOX, res=12).render(spp=1)
    assert stand_in._building is None


def test_a_large_render_and_a_cached_scene_use_their_own_kernels(cache, monkeypatch):
    monkeypatch.setattr(renderer, "QUICK_SAMPLES", 16 * 16 * 1)
    s = load_scene(CBOX, res=16)
    s.render(spp=2)  # 512 samples: beyond the (patched) quick tier's size
    assert not is_stand_in(s._module) and not reads_prm(s._module)
    monkeypatch.undo()
    monkeypatch.setenv("RDSL_CACHE_DIR", str(cache / "cache"))
    monkeypatch.setenv("RDSL_GENERIC_FIRST", "1")
    again = load_scene(CBOX, res=16)
    again.render(spp=1)  # small, but its own full tier is cached
    assert not is_stand_in(again._module) and again.from_cache


@pytest.mark.parametrize("why", ["generic already", "switched off", "integer too large"])
def test_no_stand_in(cache, monkeypatch, why):
    first_render(CBOX, spp=1, res=8)  # the generic kernels are cached
    path = CBOX
    if why == "switched off":
        monkeypatch.setenv("RDSL_GENERIC_FIRST", "0")
    if why == "integer too large":  # max_depth 2**25: only the specialized build holds it
        (cache / "big").mkdir()
        path = edited_copy(CBOX, cache / "big", 'name="max_depth" value="$max_depth"',
                           'name="max_depth" value="33554432"')
    stand_in._building = None
    s = load_scene(path, res=8, specialize=why != "generic already")
    s.render(spp=1)
    assert not is_stand_in(s._module) and stand_in._building is None
    assert reads_prm(s._module) == (why == "generic already")


def test_cli_says_which_build_rendered(cache, capsys):
    first_render(CBOX, spp=1, res=16)
    (cache / "edit").mkdir()
    path = edited_copy(CBOX, cache / "edit", RED, "0.2, 0.6, 0.3")
    out = cache / "cbox.exr"
    argv = ["render", str(path), "-D", "res=16", "--spp", "1", "-o", str(out), "--quiet"]
    assert main([*argv, "--report"]) == 0
    text = capsys.readouterr().out
    assert "generic build standing in (quick tier: LLVM O0; parameters read from PRM" in text
    assert "kernels from cache (generic build standing in)" in text.splitlines()[-1]


ROUGH = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, -6, 3" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height"
            value="16"/><rfilter type="box"/></film></sensor>
    <emitter type="constant"><rgb name="radiance" value="0.5, 0.6, 0.7"/></emitter>
    <shape type="sphere"><bsdf type="roughplastic"><float name="alpha" value="ALPHA"/>
        <rgb name="diffuse_reflectance" value="COLOUR"/></bsdf></shape>
</scene>"""


def test_tables_of_an_edited_scene_come_from_the_cache(cache, monkeypatch):
    """A rough plastic's tables (a function of its alpha): an edited colour reads them back
    from the disk without the frontend; an edited alpha computes new ones; every image is
    the specialized build's."""
    from rdsl.runtime import tables

    def write(alpha, colour):
        folder = cache / f"{alpha}-{colour.replace(', ', '-')}"
        folder.mkdir()
        path = folder / "rough.xml"
        path.write_text(ROUGH.replace("ALPHA", alpha).replace("COLOUR", colour))
        return path

    first_render(write("0.3", "0.5, 0.2, 0.1"), seed=3)
    frontend = tables._lowered
    for alpha, colour, reads in (("0.3", "0.1, 0.6, 0.2", False), ("0.1", "0.1, 0.6, 0.2", True)):
        calls = []
        monkeypatch.setattr(tables, "_lowered", lambda *a: calls.append(a) or frontend(*a))
        tables._samples.clear()
        tables._ir.clear()
        path = write(alpha, colour)
        s = load_scene(path)
        img = s.render(spp=2, seed=3)
        assert is_stand_in(s._module) and s.from_cache
        assert bool(calls) == reads, (alpha, colour)
        np.testing.assert_allclose(img, specialized_image(path, spp=2, seed=3),
                                   rtol=0, atol=1e-5)


def test_assigning_a_parameter_after_the_first_render_waits_for_the_generic_build(cache):
    """scene.params[...] = ... makes the scene generic: it loads the kernels the background
    build made rather than compiling them beside it."""
    stand_in._building = None
    s = load_scene(CBOX, res=16)
    s.render(spp=1)
    job = stand_in._building
    assert job is not None
    s.params["red.reflectance.value"] = np.array([0.3, 0.2, 0.1], np.float32)
    img = s.render(spp=2, seed=4)
    assert job.done() and s.from_cache and reads_prm(s._module)
    assert np.isfinite(img).all() and img.mean() > 0
