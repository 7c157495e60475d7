"""The scene loader on the three kinds of "Loading" failure of issue 10, each checked against
what Mitsuba 3 does with the same file (its ``scalar_*`` variants need no LLVM):

1. ``<ref id>`` to an object declared later in the file (or in a later include) resolves;
   an id that never appears, a reference cycle and a reference of the wrong category are
   clear errors at the ``<ref>``'s line;
2. relative file names in an ``<include>``d file resolve as Mitsuba's file resolver does:
   against the ``<path>`` folders and the *main* scene's folder, and a ``<path>`` in an
   included file may name a folder relative to the main scene;
3. a parameter Mitsuba 3 takes as a texture (the polarizers' angles, roughness, opacity,
   blend weight) takes every constant form Mitsuba accepts: float, one-valued or flat
   ``<spectrum>``, gray ``<rgb>``; a varying one is a clear error where rdsl needs a number.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from rdsl.runtime.scene import SceneError, load_scene_description

TRI = ("v 0 0 0", "v 1 0 0", "v 0 1 0", "f 1 2 3")
QUAD = ("v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "f 1 2 3", "f 2 4 3")


def write(path: Path, *lines: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def scene(path: Path, *body: str) -> Path:
    """A scene file: line 1 is <scene version="3.0.0">, the body starts on line 2."""
    return write(path, '<scene version="3.0.0">', *body, "</scene>")


@contextmanager
def mitsuba_in(variant: str) -> Iterator[Any]:
    """The `mitsuba` module in ``variant`` (skips without it), the previous one restored."""
    mi = pytest.importorskip("mitsuba", reason="the mitsuba package is not installed")
    previous = mi.variant()
    try:
        mi.set_variant(variant)
    except Exception as e:  # noqa: BLE001 - any failure means no cross-check here
        pytest.skip(f"mitsuba variant {variant} unavailable: {e}")
    try:
        yield mi
    finally:
        if previous is not None:
            mi.set_variant(previous)


@pytest.fixture
def mi_rgb() -> Iterator[Any]:
    with mitsuba_in("scalar_rgb") as mi:
        yield mi


# ---------------------------------------------------------------------------------------
# 1. References resolved after the whole scene is read

def test_forward_refs_resolve_like_mitsuba(tmp_path: Path, mi_rgb: Any) -> None:
    write(tmp_path / "parts" / "late.xml", '<scene version="3.0.0">',
          '<bsdf type="diffuse" id="from_include"><ref name="reflectance" id="checks"/></bsdf>',
          '<shape type="cube"><ref id="declared_in_main_later"/></shape>', "</scene>")
    path = scene(tmp_path / "scene.xml",
                 '<shape type="rectangle"><ref id="gray"/></shape>',
                 '<shape type="disk"><ref name="bsdf" id="two"/></shape>',
                 '<shape type="sphere"><ref id="from_include"/></shape>',
                 '<bsdf type="twosided" id="two"><ref id="gray"/></bsdf>',
                 '<include filename="parts/late.xml"/>',
                 '<bsdf type="diffuse" id="gray"><float name="reflectance" value="0.3"/></bsdf>',
                 '<texture type="checkerboard" id="checks">',
                 '    <rgb name="color0" value="0.1, 0.2, 0.3"/>', "</texture>",
                 '<bsdf type="conductor" id="declared_in_main_later"/>')
    assert len(mi_rgb.load_file(str(path)).shapes()) == 4  # Mitsuba takes the same file
    s = load_scene_description(path)
    rect, disk, sphere, cube = s.shapes
    assert rect.bsdf is s.ids["gray"] and rect.bsdf["reflectance"].rgb == (0.3, 0.3, 0.3)
    assert disk.bsdf is s.ids["two"] and disk.bsdf.children == [s.ids["gray"]]
    assert sphere.bsdf["reflectance"] is s.ids["checks"]
    assert s.ids["checks"]["color0"].rgb == (0.1, 0.2, 0.3)
    assert cube.bsdf.type == "conductor"


def _error(path: Path) -> str:
    with pytest.raises(SceneError) as exc:
        load_scene_description(path)
    return str(exc.value)


def test_ref_to_missing_id_names_it_at_its_line(tmp_path: Path, mi_rgb: Any) -> None:
    path = scene(tmp_path / "scene.xml", '<bsdf type="diffuse" id="gray"/>',
                 '<shape type="cube">', '    <ref id="grey"/>', "</shape>")
    with pytest.raises(Exception, match="grey"):  # Mitsuba's own exception
        mi_rgb.load_file(str(path))
    text = _error(path)
    assert f"{path}:4:5:" in text
    assert "no object with id 'grey' is declared in the scene (declared ids: gray)" in text


@pytest.mark.parametrize("body, line, cycle", [
    (['<bsdf type="twosided" id="a">', '    <ref id="a"/>', "</bsdf>"], 3,
     "bsdf 'a' -> bsdf 'a'"),
    (['<bsdf type="twosided" id="a"><ref id="b"/></bsdf>',
      '<bsdf type="twosided" id="b">', '    <bsdf type="mask"><ref id="a"/></bsdf>', "</bsdf>"],
     4, "bsdf 'a' -> bsdf 'b' -> bsdf 'mask' -> bsdf 'a'"),
])
def test_ref_cycle_is_an_error(tmp_path: Path, body: list[str], line: int, cycle: str) -> None:
    path = scene(tmp_path / "scene.xml", *body, '<shape type="cube"><ref id="a"/></shape>')
    text = _error(path)
    assert f"scene.xml:{line}:" in text and f"reference cycle {cycle}" in text, text


@pytest.mark.parametrize("body, expected, mitsuba_rejects", [
    # (Mitsuba 3.9 ignores a texture under a shape's unused name "bsdf"; rdsl names it)
    (['<texture type="checkerboard" id="t"/>', '<shape type="cube">',
      '    <ref name="bsdf" id="t"/>', "</shape>"],
     "unknown parameter 'bsdf' of shape 'cube' (a <ref> to texture 't', declared at ", False),
    (['<bsdf type="conductor" id="metal"/>', '<bsdf type="diffuse" id="d">',
      '    <ref name="reflectance" id="metal"/>', "</bsdf>"],
     ("parameter 'reflectance' of bsdf 'diffuse' expects a color (float, rgb, spectrum or "
      "texture), got a <bsdf> (a <ref> to bsdf 'metal', declared at "), True),
])
def test_ref_of_wrong_category_is_an_error(tmp_path: Path, mi_rgb: Any, body: list[str],
                                           expected: str, mitsuba_rejects: bool) -> None:
    path = scene(tmp_path / "scene.xml", *body)
    if mitsuba_rejects:
        with pytest.raises(Exception, match="metal|reflectance"):
            mi_rgb.load_file(str(path))
    text = _error(path)
    assert "scene.xml:4:5:" in text and expected in text, text


# ---------------------------------------------------------------------------------------
# 2. Files named in included scenes

def _include_tree(tmp_path: Path, part_path: str | None) -> Path:
    """main/scene.xml includes main/sub/inc/part.xml, which names meshes, a bitmap and a
    spectrum file relative to main/; ``part_path`` is a ``<path>`` in part.xml, if any."""
    main = tmp_path / "main"
    write(main / "models" / "quad.obj", *QUAD)
    write(main / "tri.obj", *TRI)
    write(main / "sub" / "inc" / "tri.obj", *QUAD)  # Mitsuba does not look next to part.xml
    write(main / "meshes" / "viapath.obj", *QUAD)
    write(main / "spd" / "flat.spd", "400 0.25", "700 0.25")
    (main / "img.png").write_bytes(b"")  # found, not read, by the loader
    write(main / "sub" / "inc" / "part.xml", '<scene version="3.0.0">',
          *([f'<path value="{part_path}"/>'] if part_path else []),
          '<shape type="obj"><string name="filename" value="models/quad.obj"/>',
          '    <bsdf type="diffuse"><spectrum name="reflectance" filename="spd/flat.spd"/>',
          "    </bsdf></shape>",
          '<shape type="obj"><string name="filename" value="tri.obj"/></shape>',
          '<shape type="obj"><string name="filename" value="viapath.obj"/></shape>',
          "</scene>")
    return main


def test_included_file_names_files_relative_to_the_main_scene(tmp_path: Path,
                                                               mi_rgb: Any) -> None:
    main = _include_tree(tmp_path, None)
    body = ['<path value="meshes"/>', '<include filename="sub/inc/part.xml"/>']
    # Mitsuba reads the bitmap (an empty file here); rdsl's loader only finds it
    theirs = [s.face_count() for s in mi_rgb.load_file(str(scene(main / "mi.xml",
                                                                 *body))).shapes()]
    path = scene(main / "scene.xml", *body,
                 '<bsdf type="diffuse" id="d"><texture type="bitmap" name="reflectance">',
                 '    <string name="filename" value="img.png"/></texture></bsdf>')
    ours = load_scene_description(path)
    faces = [len(s.mesh.faces) for s in ours.shapes]
    # tri.obj from main/, not from next to part.xml; Mitsuba loads shapes in parallel, so
    # the order of its shapes() varies from run to run
    assert faces == [2, 1, 2] and sorted(theirs) == sorted(faces)
    assert [s["filename"] for s in ours.shapes] == [
        str(main / "models" / "quad.obj"), str(main / "tri.obj"),
        str(main / "meshes" / "viapath.obj")]
    assert ours.shapes[0].bsdf["reflectance"].values == (0.25, 0.25)
    assert ours.ids["d"]["reflectance"]["filename"] == str(main / "img.png")


@pytest.mark.parametrize("value", ["meshes", "../../meshes"])
def test_path_in_included_file(tmp_path: Path, mi_rgb: Any, value: str) -> None:
    """``<path>`` in an included file may name a folder relative to the main scene (the
    issue's failure) or to the included file, as in Mitsuba; rdsl then finds files in it
    (Mitsuba 3 accepts the folder but forgets it when the include ends)."""
    main = _include_tree(tmp_path, value)
    path = scene(main / "scene.xml", '<include filename="sub/inc/part.xml"/>')
    with pytest.raises(Exception, match="viapath.obj"):  # Mitsuba's own exception
        mi_rgb.load_file(str(path))
    ours = load_scene_description(path)
    assert ours.shapes[2]["filename"] == str((main / "sub" / "inc" / value / "viapath.obj")
                                             if value.startswith("..") else
                                             main / "meshes" / "viapath.obj")
    assert [len(s.mesh.faces) for s in ours.shapes] == [2, 1, 2]


def test_path_in_main_file_comes_before_the_main_folder(tmp_path: Path, mi_rgb: Any) -> None:
    write(tmp_path / "tri.obj", *QUAD)
    write(tmp_path / "first" / "tri.obj", *TRI)
    path = scene(tmp_path / "scene.xml", '<path value="first"/>',
                 '<shape type="obj"><string name="filename" value="tri.obj"/></shape>')
    theirs = [s.face_count() for s in mi_rgb.load_file(str(path)).shapes()]
    assert [len(s.mesh.faces) for s in load_scene_description(path).shapes] == theirs == [1]


def test_missing_path_folder_is_an_error(tmp_path: Path) -> None:
    path = scene(tmp_path / "scene.xml", '<path value="nowhere"/>')
    assert "scene.xml:2:1: error: <path>: directory 'nowhere' not found" in _error(path)


# ---------------------------------------------------------------------------------------
# 3. Every constant form Mitsuba accepts for a parameter it takes as a texture

FORMS = {
    "float": '<float name="N" value="V"/>',
    "spectrum": '<spectrum name="N" value="V"/>',
    "flat_spectrum": '<spectrum name="N" value="400:V, 700:V"/>',
    "gray_rgb": '<rgb name="N" value="V"/>',
    "rgb": '<rgb name="N" value="V, V, V"/>',
}

# (variant, plugin, parameter, value, nested objects it needs)
SCALARS = [
    ("scalar_spectral_polarized", "polarizer", "theta", -45.0, ""),
    ("scalar_spectral_polarized", "retarder", "theta", 30.0, ""),
    ("scalar_spectral_polarized", "retarder", "delta", 45.0, ""),
    ("scalar_rgb", "roughconductor", "alpha", 0.3, ""),
    ("scalar_rgb", "roughdielectric", "alpha", 0.3, ""),
    ("scalar_rgb", "mask", "opacity", 0.3, '<bsdf type="diffuse"/>'),
    ("scalar_rgb", "blendbsdf", "weight", 0.3, '<bsdf type="diffuse"/><bsdf type="conductor"/>'),
]


def _bsdf_scene(tmp_path: Path, plugin: str, prop: str, nested: str) -> Path:
    return scene(tmp_path / "scene.xml", f'<bsdf type="{plugin}" id="b">', f"    {prop}",
                 f"    {nested}", "</bsdf>")


# every form for every case, but a negative value only as a float or a one-value spectrum:
# Mitsuba's flat spectra and 3-value rgb hold non-negative numbers only
SCALAR_FORMS = [(form, *case) for case in SCALARS for form in FORMS
                if not (case[3] < 0 and form in ("flat_spectrum", "rgb"))]


@pytest.mark.parametrize("form, variant, plugin, name, value, nested", SCALAR_FORMS,
                         ids=[f"{c[2]}-{c[3]}={c[4]:g}-{c[0]}" for c in SCALAR_FORMS])
def test_scalar_texture_params_take_constant_forms(tmp_path: Path, variant: str, plugin: str,
                                                   name: str, value: float, nested: str,
                                                   form: str) -> None:
    prop = FORMS[form].replace('"N"', f'"{name}"').replace("V", f"{value:g}")
    path = _bsdf_scene(tmp_path, plugin, prop, nested)
    with mitsuba_in(variant) as mi:
        mi.load_file(str(path))  # Mitsuba accepts this form
    b = load_scene_description(path).ids["b"]
    assert b[name] == value and isinstance(b[name], float)


@pytest.mark.parametrize("prop, expected", [
    ('<spectrum name="theta" value="400:10, 700:20"/>',
     ("parameter 'theta' of bsdf 'polarizer' takes one number (or a texture where Mitsuba "
     "does), but the <spectrum> given varies (10, 20); give one value")),
    ('<rgb name="theta" value="10, 20, 30"/>',
     "but the <rgb> given varies (10, 20, 30); give one value"),
    ('<texture type="checkerboard" name="theta"/>',
     ("parameter 'theta' of bsdf 'polarizer' expects a constant float (a float, or a "
      "spectrum or rgb with one value), got a <texture>")),
])
def test_polarizer_angle_rdsl_cannot_take_is_a_clear_error(tmp_path: Path, prop: str,
                                                           expected: str) -> None:
    path = _bsdf_scene(tmp_path, "polarizer", prop, "")
    text = _error(path)
    assert "scene.xml:3:5:" in text and expected in text, text


def test_negative_color_is_still_an_error(tmp_path: Path) -> None:
    path = scene(tmp_path / "scene.xml", '<bsdf type="diffuse">',
                 '    <spectrum name="reflectance" value="-0.5"/>', "</bsdf>")
    text = _error(path)
    assert "scene.xml:3:5:" in text and "a color must be non-negative, got -0.5" in text
