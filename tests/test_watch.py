"""``rdsl render --watch``: the loop driven in-process (runtime/render/watch.py) on a small
Cornell box.  An edit of an included XML file writes a new image equal to a direct render of
the edited scene; a broken edit keeps the loop and the last image; a touched file renders
nothing; a reload parses only changed meshes and keeps the Embree scene when the geometry is
the same; Ctrl-C ends ``rdsl render --watch`` with status 0."""

from __future__ import annotations

import io
import os
import re
import threading
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rdsl.runtime.embree")

from rdsl.cli import main
from rdsl.runtime.render import watch as watch_module
from rdsl.runtime.render.image import read_exr, write_render
from rdsl.runtime.render.renderer import RenderCancelled, load_scene
from rdsl.runtime.render.watch import Watcher, WatchJob, preview_spp
from rdsl.runtime.scene import meshes

CBOX = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "cbox" / "cbox.xml"
pytestmark = pytest.mark.skipif(not CBOX.is_file(), reason=f"needs {CBOX}")

GREEN = "0.105421, 0.37798, 0.076425"
GREEN_XML = ('<scene version="3.0.0"><bsdf type="diffuse" id="green">'
             '<rgb name="reflectance" value="{}"/></bsdf></scene>\n')
SMALL = {"res": 16}  # the generic build of this size is test_generic_build's too
SPP, SEED = 4, 1


def write(path: Path, text: str) -> None:
    """Write ``text`` and move the modification time on: two writes within one tick of
    the file system's clock must still look like an edit (a person is never that fast)."""
    old = path.stat().st_mtime_ns if path.exists() else 0
    path.write_text(text)
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, max(st.st_mtime_ns, old + 10_000_000)))


def cbox_with_include(folder: Path) -> Path:
    """The Cornell box with its green BSDF in an included file, green.xml."""
    text = CBOX.read_text()
    green = re.search(r'<bsdf type="diffuse" id="green">.*?</bsdf>', text, re.DOTALL)
    assert green is not None and GREEN in green.group(0)
    scene = folder / "cbox.xml"
    scene.write_text(text.replace(green.group(0), '<include filename="green.xml"/>'))
    (folder / "green.xml").write_text(GREEN_XML.format(GREEN))
    return scene


def first_render(scene_path: Path, out: Path) -> tuple[object, WatchJob, io.StringIO,
                                                          io.StringIO]:
    """What ``rdsl render --watch`` does before the loop, and a watcher with captured
    output."""
    scene = load_scene(scene_path, specialize=False, **SMALL)
    write_render(out, scene.render(spp=SPP, seed=SEED), scene.channel_names)
    job = WatchJob(out, spp=SPP, seed=SEED)
    return scene, job, io.StringIO(), io.StringIO()


def direct(scene_path: Path) -> np.ndarray:
    return load_scene(scene_path, specialize=False, **SMALL).render(spp=SPP, seed=SEED)


def test_an_edit_of_an_included_file_writes_the_new_image(tmp_path):
    path = cbox_with_include(tmp_path)
    out = tmp_path / "out.exr"
    scene, job, out_text, err_text = first_render(path, out)
    before = read_exr(out)
    w = Watcher(scene, job, out_text, err_text)
    assert (tmp_path / "green.xml").resolve() in w.files.stamps

    def edit(i: int) -> None:
        if i == 0:
            write(tmp_path / "green.xml", GREEN_XML.format("0.9, 0.1, 0.8"))

    assert w.run(poll=0.01, max_updates=1, on_poll=edit) == 0
    after = read_exr(out)
    expected = direct(path)
    assert np.allclose(after.mean(axis=(0, 1)), expected.mean(axis=(0, 1)), rtol=1e-6)
    assert np.array_equal(after, expected)  # the same kernel, parameters and seed
    # the green wall turned magenta: red and blue went up, green down
    d = after.mean(axis=(0, 1)) - before.mean(axis=(0, 1))
    assert d[0] > 0 and d[2] > 0 and d[1] < 0, d
    line = out_text.getvalue().splitlines()[-1]
    # the generic build reads the colour at run time: no compile, and the box did not move
    assert "green.xml changed" in line and "kernels from cache" in line, line
    assert "geometry reused" in line and str(out) in line, line
    assert not err_text.getvalue()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cbox.xml", "green.xml",
                                                         "out.exr", "out.png"]


def test_a_broken_edit_keeps_the_loop_and_the_last_image(tmp_path):
    path = cbox_with_include(tmp_path)
    out = tmp_path / "out.exr"
    scene, job, out_text, err_text = first_render(path, out)
    good = out.read_bytes()
    w = Watcher(scene, job, out_text, err_text)
    seen: list[bytes] = []

    def edit(i: int) -> None:
        if i == 0:
            write(tmp_path / "green.xml", GREEN_XML.format("0.9, 0.1, 0.8").replace(
                "</bsdf>", ""))
        elif w.updates == 1 and not seen:  # the broken edit has been handled
            seen.append(out.read_bytes())
            write(tmp_path / "green.xml", GREEN_XML.format("0.2, 0.2, 0.9"))

    assert w.run(poll=0.01, max_updates=2, on_poll=edit) == 0
    err = err_text.getvalue()
    assert re.search(r"green\.xml:1:\d+: error: ", err), err
    assert "waiting for a fix" in err
    assert seen == [good]  # the old image stayed while the scene was broken
    assert np.array_equal(read_exr(out), direct(path))


def test_a_touched_file_renders_nothing(tmp_path):
    path = cbox_with_include(tmp_path)
    out = tmp_path / "out.exr"
    scene, job, out_text, err_text = first_render(path, out)
    stamp = out.stat().st_mtime_ns
    w = Watcher(scene, job, out_text, err_text)
    stop = threading.Event()

    def touch(i: int) -> None:
        if i == 0:
            write(path, path.read_text())
        elif i == 3:
            stop.set()

    assert w.run(poll=0.01, stop=stop, on_poll=touch) == 0
    assert w.updates == 0 and out.stat().st_mtime_ns == stamp
    assert "cbox.xml: touched, content unchanged" in out_text.getvalue()


def test_a_reload_parses_only_changed_meshes(tmp_path, monkeypatch):
    quad = "v -0.5 -0.5 0\nv 0.5 -0.5 0\nv 0.5 0.5 0\nv -0.5 0.5 0\nf 1 2 3\nf 1 3 4\n"
    (tmp_path / "quad.obj").write_text(quad)
    scene_path = tmp_path / "cbox.xml"
    scene_path.write_text(CBOX.read_text().replace(
        "</scene>", '<shape type="obj"><string name="filename" value="quad.obj"/>'
        '<ref id="red"/></shape></scene>'))
    calls = []
    real = meshes.load_obj
    monkeypatch.setattr(meshes, "load_obj", lambda *a: calls.append(a) or real(*a))
    scene = load_scene(scene_path, specialize=False, **SMALL)
    assert len(calls) == 1 and (tmp_path / "quad.obj").resolve() in scene.reads.files
    write(scene_path, scene_path.read_text().replace(GREEN, "0.5, 0.5, 0.5"))
    again = scene.reload()
    assert len(calls) == 1  # the mesh file did not change: its parse is reused
    assert again.geometry_reused and again.embree is scene.embree
    write(tmp_path / "quad.obj", quad.replace("v 0.5 0.5 0", "v 0.6 0.5 0"))
    moved = again.reload()
    assert len(calls) == 2 and not moved.geometry_reused
    assert moved.embree is not scene.embree


def test_a_cancelled_render_stops():
    scene = load_scene(CBOX, specialize=False, **SMALL)
    asked = []
    with pytest.raises(RenderCancelled):
        scene.render(spp=64, seed=SEED, cancel=lambda: asked.append(1) or True)
    assert asked == [1]  # after the first batch


def test_the_first_image_after_a_change_is_quick():
    assert preview_spp(64, 0.001) == 0  # 64 spp take 0.064 s: no need for a first image
    n = preview_spp(64, 0.04)  # 2.56 s for the whole image
    assert n == 4 and n * 0.04 <= watch_module.PREVIEW_SECONDS < 2 * n * 0.04
    assert preview_spp(16, 0.1) == 2  # at most a quarter of the samples
    assert preview_spp(4, 10.0) == 1


def test_ctrl_c_ends_the_command_with_status_0(tmp_path, monkeypatch, capsys):
    path = cbox_with_include(tmp_path)

    def interrupt(_: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(watch_module.time, "sleep", interrupt)
    out = tmp_path / "o.exr"
    assert main(["render", str(path), "--watch", "--quiet", "--spp", "1", "-D", "res=16",
                 "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "watching" in text and text.rstrip().endswith("watch: stopped")
    assert out.is_file() and (tmp_path / "o.png").is_file()


def test_a_new_plugin_file_next_to_the_scene_is_seen(tmp_path):
    """A .rdsl file added to the scene's folder may change what a name resolves to: here a
    user `diffuse` that shadows the stdlib's (and reflects half as much)."""
    import warnings

    path = tmp_path / "cbox.xml"
    path.write_text(CBOX.read_text())
    out = tmp_path / "out.exr"
    scene, job, out_text, err_text = first_render(path, out)
    before = read_exr(out)
    w = Watcher(scene, job, out_text, err_text)
    stdlib = Path(__file__).resolve().parents[1] / "stdlib" / "bsdf" / "diffuse.rdsl"
    half = stdlib.read_text().replace("depolarized(reflectance(si)",
                                      "depolarized(0.5 * reflectance(si)")
    assert half.count("0.5 * reflectance") == 2

    def edit(i: int) -> None:
        if i == 0:
            write(tmp_path / "diffuse.rdsl", half)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the shadowing warning
        assert w.run(poll=0.01, max_updates=1, on_poll=edit) == 0
    after = read_exr(out)
    assert after.mean() < 0.8 * before.mean()
    assert "changed: scene reloaded" in out_text.getvalue(), out_text.getvalue()
