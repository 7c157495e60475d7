"""User plugins in scenes (docs/plugins.md): discovery, parameters, errors, and renders.

The independent truth for rendering is the stdlib: a copy of ``diffuse`` (and of the
``area`` emitter) under other names, next to a copy of the Cornell box, must give the stdlib
image bit for bit, in every way a scene is built (specialized, generic, nested in
``blendbsdf``, spectral, polarized).  Search order, shadowing and each user mistake are
checked on the loaded scene description (no compile).  The example plugins of
examples/plugins/ are checked against closed forms: Oren-Nayar against PBRT's formula and
against Lambert at sigma = 0, its sampling by chi-square; the wood texture's range.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rdsl
from _scenes import CBOX
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime import plugins as registry
from rdsl.runtime.scene import SceneError, load_scene_description
from rdsl.runtime.testkit.chi2 import chi2_directions
from rdsl.runtime.testkit.harness import Harness, declarations

ROOT = Path(__file__).resolve().parents[1]
STDLIB = ROOT / "stdlib"
EXAMPLES = ROOT / "examples" / "plugins"
SMALL = {"res": 16, "spp": 2}
f32 = np.float32

pytestmark = pytest.mark.skipif(not CBOX.is_file(), reason=f"{CBOX} is not present")


def renamed(kind_file: str, old: str, new: str) -> str:
    """A stdlib plugin's source with the plugin renamed."""
    src = (STDLIB / kind_file).read_text()
    out = re.sub(rf"^(bsdf|emitter|texture) {old} \{{", rf"\1 {new} {{", src, flags=re.MULTILINE)
    assert out != src
    return out


def cbox_with(folder: Path, bsdf: str = "diffuse", emitter: str = "area",
              name: str = "cbox.xml") -> Path:
    """The Cornell box written to ``folder`` with its BSDF and emitter types replaced."""
    text = CBOX.read_text().replace('type="diffuse"', f'type="{bsdf}"')
    text = text.replace('<emitter type="area">', f'<emitter type="{emitter}">')
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)
    return folder / name


def scene(folder: Path, bsdf_xml: str, name: str = "scene.xml") -> Path:
    """A one-rectangle scene whose BSDF is ``bsdf_xml`` (line 3 of the file)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text('<scene version="3.0.0">\n    <shape type="rectangle">\n'
                    f'{bsdf_xml}\n    </shape>\n</scene>\n')
    return path


@pytest.fixture(scope="module")
def user(tmp_path_factory) -> Path:
    """A folder with `mydiffuse` and `myarea` (the stdlib's diffuse and area, renamed) next
    to a copy of the Cornell box that uses them."""
    d = tmp_path_factory.mktemp("user")
    (d / "mydiffuse.rdsl").write_text(renamed("bsdf/diffuse.rdsl", "diffuse", "mydiffuse"))
    (d / "myarea.rdsl").write_text(renamed("emitter/area.rdsl", "area", "myarea"))
    cbox_with(d, "mydiffuse", "myarea")
    return d


def render(path: Path, **kw) -> np.ndarray:
    return rdsl.load_scene(path, **SMALL, **kw).render()


# ---------------------------------------------------------------------------- renders

@pytest.mark.parametrize("variant,specialize", [("rgb", True), ("rgb", False),
                                                ("spectral", True), ("mono_polarized", True)])
def test_renamed_diffuse_renders_bit_identical(user, variant, specialize):
    mine = rdsl.load_scene(user / "cbox.xml", variant=variant, specialize=specialize, **SMALL)
    assert {"mydiffuse", "myarea"} <= set(mine.desc.plugins)
    got = mine.render()
    want = render(CBOX, variant=variant, specialize=specialize)
    assert np.array_equal(got, want)
    assert any("instance(s) of mydiffuse" in line for line in mine.report)  # --report


def test_user_bsdf_nested_in_blendbsdf(user, tmp_path):
    def blend(a: str, b: str) -> str:
        return (f'<bsdf type="blendbsdf"><float name="weight" value="0.3"/>'
                f'<bsdf type="{a}"><rgb name="reflectance" value="0.8, 0.2, 0.1"/></bsdf>'
                f'<bsdf type="{b}"><float name="reflectance" value="0.4"/></bsdf></bsdf>')

    text = CBOX.read_text()
    for folder, (a, b) in (("mine", ("mydiffuse", "mydiffuse")), ("std", ("diffuse", "diffuse"))):
        out = text.replace('<ref id="white"/>\n    </shape>\n    <shape type="rectangle" '
                           'id="ceiling">', f'{blend(a, b)}\n    </shape>\n    <shape '
                           'type="rectangle" id="ceiling">')
        assert out != text
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "cbox.xml").write_text(out)
    got = render(tmp_path / "mine" / "cbox.xml", plugins=[user])
    assert np.array_equal(got, render(tmp_path / "std" / "cbox.xml"))


def test_user_texture_renders():
    """A user texture (the wood example) renders, on a reflectance and, through its eval_1,
    on a roughness."""
    img = render(EXAMPLES / "wood.xml")
    assert img.shape == (16, 16, 3) and np.all(np.isfinite(img)) and img.mean() > 0.01


@pytest.mark.parametrize("variant,specialize", [("rgb", True), ("rgb", False),
                                                ("mono", True)])
def test_a_texture_without_eval_1_sets_a_colour(tmp_path, variant, specialize):
    """eval_1 is needed only for a Float parameter (docs/plugins.md); a texture without it
    on a reflectance once failed to compile ("plugin `flat` has no function `eval_1`", no
    file): the texture's dispatch covered eval_1 of every texture.  It renders as the same
    constant colour given as an <rgb>."""
    (tmp_path / "flat.rdsl").write_text(
        "texture flat {\n    param c: Spectrum = 0.5;\n"
        "    fn eval(si: Surface) -> Spectrum { return c; }\n}\n")
    rgb = '<rgb name="reflectance" value="0.885809, 0.698859, 0.666422"/>'
    text = CBOX.read_text()
    assert rgb in text
    (tmp_path / "cbox.xml").write_text(text.replace(
        rgb, '<texture type="flat" name="reflectance">'
        f'{rgb.replace("reflectance", "c")}</texture>'))
    got = render(tmp_path / "cbox.xml", variant=variant, specialize=specialize)
    want = render(CBOX, variant=variant, specialize=specialize)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_a_colour_from_float_params_in_the_generic_spectral_build(tmp_path):
    """`Spectrum(red, 0.5, 0.2)` of a Float param folds to a constant colour when the kernel
    is specialized, but is computed in the generic build (`--no-specialize`, `--watch`'s
    default): the diagnostic says so and what to declare instead."""
    (tmp_path / "tinted.rdsl").write_text(
        "texture tinted {\n    param red: Float = 0.7;\n"
        "    fn eval(si: Surface) -> Spectrum { return Spectrum(red, 0.5, 0.2); }\n"
        "    fn eval_1(si: Surface) -> Float { return red; }\n}\n")
    text = CBOX.read_text().replace(
        '<rgb name="reflectance" value="0.885809, 0.698859, 0.666422"/>',
        '<texture type="tinted" name="reflectance"><float name="red" value="0.9"/></texture>')
    (tmp_path / "cbox.xml").write_text(text)
    img = render(tmp_path / "cbox.xml", variant="spectral")  # specialized: a constant
    assert np.all(np.isfinite(img)) and img.mean() > 0.01
    with pytest.raises(CompileError) as e:
        render(tmp_path / "cbox.xml", variant="spectral", specialize=False)
    assert f"{tmp_path / 'tinted.rdsl'}:3:" in str(e.value) or "tinted.rdsl:3:" in str(e.value)
    assert "--no-specialize or --watch" in str(e.value)
    assert "make the colour a `Spectrum` param" in str(e.value)


# ---------------------------------------------------------------------------- discovery

def test_search_order_and_shadowing(tmp_path, monkeypatch):
    """Scene folder, then --plugins, then $RDSL_PLUGIN_PATH, then the stdlib; each
    shadowing names both files."""
    src = renamed("bsdf/diffuse.rdsl", "diffuse", "shade")
    for d in ("scene", "cli", "env"):
        (tmp_path / d).mkdir()
        (tmp_path / d / "shade.rdsl").write_text(src)
    monkeypatch.setenv("RDSL_PLUGIN_PATH", str(tmp_path / "env"))
    path = scene(tmp_path / "scene", '<bsdf type="shade"/>')
    with pytest.warns(UserWarning) as w:
        desc = load_scene_description(path, plugins=[tmp_path / "cli"])
    assert desc.plugins["shade"].path == tmp_path / "scene" / "shade.rdsl"
    text = " ".join(str(x.message) for x in w)
    for d in ("scene", "cli", "env"):
        assert str(tmp_path / d / "shade.rdsl") in text
    (tmp_path / "scene" / "shade.rdsl").unlink()
    with pytest.warns(UserWarning):
        desc = load_scene_description(path, plugins=[tmp_path / "cli"])
    assert desc.plugins["shade"].path == tmp_path / "cli" / "shade.rdsl"
    (tmp_path / "cli" / "shade.rdsl").unlink()
    desc = load_scene_description(path, plugins=[tmp_path / "cli"])
    assert desc.plugins["shade"].path == tmp_path / "env" / "shade.rdsl"


def test_a_declaration_with_its_brace_on_the_next_line_is_found(tmp_path):
    """`bsdf NAME` with `{` on the next line (valid rdsl) was missed by the folder's index:
    "unknown bsdf plugin"; a declaration in a line comment is still no declaration."""
    src = renamed("bsdf/diffuse.rdsl", "diffuse", "allman").replace("bsdf allman {",
                                                                     "bsdf allman\n{")
    (tmp_path / "allman.rdsl").write_text(src)
    (tmp_path / "other.rdsl").write_text("// bsdf commented {\n")
    desc = load_scene_description(scene(tmp_path, '<bsdf type="allman"/>'))
    assert desc.plugins["allman"].path == tmp_path / "allman.rdsl"
    assert desc.plugins["allman"].line == src.splitlines().index("bsdf allman") + 1
    with pytest.raises(SceneError, match="unknown bsdf plugin 'commented'"):
        load_scene_description(scene(tmp_path, '<bsdf type="commented"/>', "s2.xml"))


def test_shadowing_a_stdlib_plugin_warns_naming_both_files(tmp_path):
    (tmp_path / "diffuse.rdsl").write_text((STDLIB / "bsdf" / "diffuse.rdsl").read_text())
    path = scene(tmp_path, '<bsdf type="diffuse"/>')
    with pytest.warns(UserWarning, match="shadows") as w:
        desc = load_scene_description(path)
    assert str(tmp_path / "diffuse.rdsl") in str(w[0].message)
    assert str(STDLIB / "bsdf" / "diffuse.rdsl") in str(w[0].message)
    assert desc.plugins["diffuse"].path == tmp_path / "diffuse.rdsl"
    assert desc.shapes[0].bsdf.decl is not None  # its own params, not Mitsuba's


def test_cli_prints_the_shadowing_warning_once_as_warning(tmp_path, capsys):
    """`rdsl render` prints the shadowing warning as docs/plugins.md shows it, `file:line:
    warning: ...` (it printed `warning: file:line: warning: ...`)."""
    from rdsl.cli import main

    src = (STDLIB / "bsdf" / "diffuse.rdsl").read_text()
    path = cbox_with(tmp_path / "s")
    (tmp_path / "s" / "diffuse.rdsl").write_text(src)
    assert main(["render", str(path), "--spp", "1", "-D", "res=4", "--quiet",
                 "-o", str(tmp_path / "o.exr")]) == 0
    err = capsys.readouterr().err
    line = src.splitlines().index("bsdf diffuse {") + 1
    want = f"{tmp_path / 's' / 'diffuse.rdsl'}:{line}: warning: bsdf plugin `diffuse` shadows"
    assert any(t.startswith(want) for t in err.splitlines()), err
    assert err.count("warning:") == 1, err


def test_nan_samples_warning_names_the_scenes_own_plugins(tmp_path, capsys):
    from rdsl.cli import main

    src = renamed("bsdf/diffuse.rdsl", "diffuse", "nanny").replace(
        "weight: depolarized(reflectance(si))", "weight: depolarized(reflectance(si)) * sqrt(-1.0)")
    (tmp_path / "nanny.rdsl").write_text(src)
    path = cbox_with(tmp_path, "nanny")
    assert main(["render", str(path), "--spp", "1", "-D", "res=4", "--quiet",
                 "-o", str(tmp_path / "o.exr")]) == 0
    err = capsys.readouterr().err
    assert "samples were NaN or infinite" in err, err
    assert f"`rdsl test-plugin FILE` sweeps for NaN: {tmp_path / 'nanny.rdsl'}" in err, err


def test_a_combinators_name_is_an_error_without_a_shadowing_warning(tmp_path, recwarn):
    (tmp_path / "mytwosided.rdsl").write_text(renamed("bsdf/diffuse.rdsl", "diffuse",
                                                       "twosided"))
    with pytest.raises(CompileError, match="name of one of rdsl's built-in bsdf combinators"):
        load_scene_description(scene(tmp_path, '<bsdf type="twosided"/>'))
    assert not [w for w in recwarn if "shadows" in str(w.message)]


INTEGRATOR = """import render.integrator;
integrator flat {
    fn sample(scene: Scene, ray: Ray, sampler: Sampler) -> Spectrum { return Spectrum(1.0); }
}
"""


@pytest.mark.parametrize("file, src, xml, message", [
    ("flat.rdsl", INTEGRATOR, '<bsdf type="flat"/>',
     "`flat` is declared as an integrator plugin at {dir}/flat.rdsl:2, not as a bsdf plugin: "
     "a <bsdf> needs `bsdf flat {{`"),
    ("mine.rdsl", renamed("bsdf/diffuse.rdsl", "diffuse", "mine"),
     '<bsdf type="diffuse"><texture type="mine" name="reflectance"/></bsdf>',
     "`mine` is declared as a bsdf plugin at {dir}/mine.rdsl:9, not as a texture plugin"),
    ("mine.rdsl", renamed("bsdf/diffuse.rdsl", "diffuse", "mine"),
     '<bsdf type="diffuse"/><emitter type="mine"/>',
     "not as an emitter plugin: an <emitter> needs `emitter mine {{`"),
], ids=["integrator-as-bsdf", "bsdf-as-texture", "bsdf-as-emitter"])
def test_a_plugin_of_another_kind_is_named_in_the_error(tmp_path, file, src, xml, message):
    (tmp_path / file).write_text(src)
    path = scene(tmp_path, xml)
    with pytest.raises(SceneError) as e:
        load_scene_description(path)
    text = str(e.value)
    assert text.startswith(f"{path}:3:") and "unknown" in text, text
    assert message.format(dir=tmp_path) in text, text


def test_load_scene_plugins_and_register_plugin(tmp_path, monkeypatch):
    monkeypatch.setattr(registry, "_REGISTERED", [])
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "velvety.rdsl").write_text(
        renamed("bsdf/diffuse.rdsl", "diffuse", "velvety"))
    path = scene(tmp_path / "s", '<bsdf type="velvety"><float name="reflectance" '
                 'value="0.3"/></bsdf>')
    with pytest.raises(SceneError, match="unknown bsdf plugin 'velvety'"):
        load_scene_description(path)
    desc = load_scene_description(path, plugins=[tmp_path / "lib"])
    assert desc.plugins["velvety"].path == tmp_path / "lib" / "velvety.rdsl"
    # a file, and source text (written to the cache), both registered for every scene
    assert rdsl.register_plugin(tmp_path / "lib" / "velvety.rdsl") == ["velvety"]
    assert load_scene_description(path).plugins["velvety"].path == tmp_path / "lib" / \
        "velvety.rdsl"
    source = renamed("bsdf/diffuse.rdsl", "diffuse", "velvety")
    assert rdsl.register_plugin(source) == ["velvety"]  # replaces the file's registration
    got = load_scene_description(path).plugins["velvety"].path
    assert got.is_relative_to(tmp_path / "cache") and got.read_text() == source
    with pytest.raises(CompileError, match="declares no plugin"):
        rdsl.register_plugin("fn f() -> Float { return 1.0; }\n")


def test_registered_source_named_like_a_stdlib_module_renders(tmp_path, monkeypatch):
    """Source text is written to a file named after its plugin: a plugin `frame` (which
    imports the stdlib's `frame`) was written to frame.rdsl, which then imported itself
    ("import cycle: frame.rdsl -> frame.rdsl")."""
    monkeypatch.setattr(registry, "_REGISTERED", [])
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    assert rdsl.register_plugin(renamed("bsdf/diffuse.rdsl", "diffuse", "frame")) == ["frame"]
    text = CBOX.read_text().replace('type="diffuse"', 'type="frame"')
    (tmp_path / "cbox.xml").write_text(text)
    got = render(tmp_path / "cbox.xml")
    assert np.array_equal(got, render(CBOX))


def test_a_plugin_file_named_like_a_stdlib_module_it_imports(tmp_path):
    """A warp.rdsl next to the scene that imports `warp` imports itself: the cycle's
    diagnostic says why and what to do."""
    (tmp_path / "warp.rdsl").write_text(renamed("bsdf/diffuse.rdsl", "diffuse", "mywarp"))
    with pytest.raises(CompileError) as e:
        load_scene_description(scene(tmp_path, '<bsdf type="mywarp"/>'))
    text = str(e.value)
    assert "warp.rdsl:6:1: error: import cycle: warp.rdsl -> warp.rdsl: the file's name " \
        "hides the stdlib's `warp`" in text and "rename the file" in text, text


def test_cli_plugins_option(user, tmp_path):
    """`rdsl render --plugins DIR` finds a plugin for a scene elsewhere."""
    path = cbox_with(tmp_path / "elsewhere", "mydiffuse", "area")
    cmd = [sys.executable, "-m", "rdsl.cli", "render", str(path), "-o", str(tmp_path / "o.exr"),
           "-D", "res=8", "-D", "spp=1", "--quiet"]
    bad = subprocess.run(cmd, check=False, capture_output=True, text=True, cwd=tmp_path)
    assert bad.returncode == 1 and "unknown bsdf plugin 'mydiffuse'" in bad.stderr
    assert "Traceback" not in bad.stderr
    ok = subprocess.run(cmd + ["--plugins", str(user)], check=False, capture_output=True,
                        text=True, cwd=tmp_path)
    assert ok.returncode == 0, ok.stderr
    assert (tmp_path / "o.exr").is_file()


# ---------------------------------------------------------------------------- errors

def test_syntax_error_in_plugin_is_a_diagnostic_at_its_line(tmp_path):
    src = renamed("bsdf/diffuse.rdsl", "diffuse", "broken").replace(
        "let cos_theta_o = cos_theta(wo);", "let cos_theta_o = cos_theta(wo)")
    (tmp_path / "broken.rdsl").write_text(src)
    with pytest.raises(CompileError) as e:
        load_scene_description(scene(tmp_path, '<bsdf type="broken"/>'))
    line = src.splitlines().index("        let cos_theta_o = cos_theta(wo)") + 1
    assert f"broken.rdsl:{line}:40: error: expected `;`" in str(e.value), str(e.value)


def test_missing_interface_function_is_a_diagnostic_at_the_plugin(tmp_path):
    src = renamed("bsdf/diffuse.rdsl", "diffuse", "nopdf")
    src = re.sub(r"    fn pdf\(.*?\n    }\n", "", src, flags=re.DOTALL)
    (tmp_path / "nopdf.rdsl").write_text(src)
    with pytest.raises(CompileError) as e:
        load_scene_description(scene(tmp_path, '<bsdf type="nopdf"/>'))
    line = src.splitlines().index("bsdf nopdf {") + 1
    assert f"nopdf.rdsl:{line}:" in str(e.value)
    assert "missing the required function `fn pdf(si: Surface, wo: Vec3) -> Float`" in \
        str(e.value)


STRIPES = """texture stripes {
    param count: Int = 4;
    fn on(si: Surface) -> Bool {
        let x = si.uv.x * Float(count);
        return x - floor(x) < 0.5;
    }
    fn eval(si: Surface) -> Spectrum { return Spectrum(select(on(si), 0.8, 0.2)); }
    fn eval_1(si: Surface) -> Float { return select(on(si), 0.8, 0.2); }
}
"""


@pytest.mark.parametrize("kind, old, new, found", [
    # a texture's eval_1 giving a colour: once an internal error (`mul` on mismatched
    # aggregates) where the texture set a Float parameter
    ("texture", "fn eval_1(si: Surface) -> Float { return select(on(si), 0.8, 0.2); }",
     "fn eval_1(si: Surface) -> Spectrum { return Spectrum(0.5); }",
     "found `eval_1(Surface) -> Spectrum`"),
    # one more parameter: once "parameter `k` of `stripes` has no value", with no file
    ("texture", "fn eval_1(si: Surface) -> Float", "fn eval_1(si: Surface, k: Float) -> Float",
     "found `eval_1(Surface, Float) -> Float`"),
    ("bsdf", "fn albedo_two_sided() -> Bool { return true; }",
     "fn albedo_two_sided() -> Float { return 1.0; }", "found `albedo_two_sided() -> Float`"),
    ("bsdf", "fn albedo_two_sided() -> Bool { return true; }",
     "fn disperses(x: Float) -> Bool { return x > 0.5; }", "found `disperses(Float) -> Bool`"),
], ids=["eval_1-colour", "eval_1-two-args", "albedo_two_sided-float", "disperses-arg"])
def test_optional_interface_function_with_a_wrong_signature(tmp_path, kind, old, new, found):
    """An optional function of an interface (a texture's `eval_1`, a BSDF's `disperses`...)
    that the plugin defines must have the interface's signature: a diagnostic at its line."""
    base = STRIPES if kind == "texture" else renamed("bsdf/diffuse.rdsl", "diffuse", "mine")
    assert old in base
    src = base.replace(old, new)
    name = "stripes" if kind == "texture" else "mine"
    (tmp_path / f"{name}.rdsl").write_text(src)
    bsdf = ('<bsdf type="roughconductor"><texture type="stripes" name="alpha"/></bsdf>'
            if kind == "texture" else '<bsdf type="mine"/>')
    with pytest.raises(CompileError) as e:
        load_scene_description(scene(tmp_path, bsdf))
    mname = new.split("(")[0].split()[-1]
    line = next(i for i, t in enumerate(src.splitlines(), 1) if f"fn {mname}(" in t)
    text = str(e.value)
    assert f"{name}.rdsl:{line}:" in text, text
    assert f"`{name}.{mname}` has the wrong signature: expected `fn {mname}(" in text, text
    assert found in text, text


def _param_line(path: Path, name: str) -> int:
    return next(i for i, t in enumerate(path.read_text().splitlines(), 1)
                if re.match(rf"\s*param {name}\b", t))


def test_wrong_parameter_type_names_xml_line_and_declaration(tmp_path):
    (tmp_path / "orennayar.rdsl").write_text((EXAMPLES / "orennayar.rdsl").read_text())
    decl = f"{tmp_path / 'orennayar.rdsl'}:{_param_line(tmp_path / 'orennayar.rdsl', 'sigma')}"
    # a Float takes a gray <rgb> (Mitsuba's texture forms) but not a varying one
    for value, expected in (('<boolean name="sigma" value="true"/>',
                             ("expects a float or a texture (or a constant spectrum or rgb), "
                             "got <boolean>")),
                            ('<rgb name="sigma" value="0.1, 0.2, 0.3"/>',
                             "the <rgb> given varies (0.1, 0.2, 0.3); give one value")):
        path = scene(tmp_path, f'<bsdf type="orennayar">\n    {value}\n</bsdf>')
        with pytest.raises(SceneError) as e:
            load_scene_description(path)
        text = str(e.value)
        assert text.startswith(f"{path}:4:"), text
        assert expected in text and decl in text, text
    assert "`param sigma: Float`" in text


def test_negative_integer_for_an_unsigned_param_is_an_error(tmp_path):
    """A `UInt` param given a negative <integer> (once taken, wrapped to 2^32 - 3)."""
    (tmp_path / "seeded.rdsl").write_text(
        "texture seeded {\n    param seed: UInt = 1u;\n"
        "    fn eval(si: Surface) -> Spectrum { return Spectrum(Float(seed % 7u) * 0.1); }\n}\n")
    ok = scene(tmp_path, '<bsdf type="diffuse"><texture type="seeded" name="reflectance">'
               '<integer name="seed" value="3"/></texture></bsdf>')
    load_scene_description(ok)
    path = scene(tmp_path, '<bsdf type="diffuse"><texture type="seeded" name="reflectance">'
                 '<integer name="seed" value="-3"/></texture></bsdf>', "bad.xml")
    with pytest.raises(SceneError) as e:
        load_scene_description(path)
    text = str(e.value)
    assert text.startswith(f"{path}:3:"), text
    assert "parameter 'seed' of texture 'seeded'" in text and "cannot be -3" in text, text
    assert f"`param seed: UInt` at {tmp_path / 'seeded.rdsl'}:2" in text, text


def test_unknown_and_string_properties_are_errors(tmp_path):
    (tmp_path / "orennayar.rdsl").write_text((EXAMPLES / "orennayar.rdsl").read_text())
    path = scene(tmp_path, '<bsdf type="orennayar">\n    <float name="roughness" value="1"/>'
                 '\n</bsdf>')
    with pytest.raises(SceneError) as e:
        load_scene_description(path)
    assert str(e.value).startswith(f"{path}:4:")
    assert "unknown parameter 'roughness'" in str(e.value)
    assert "accepted: reflectance, sigma" in str(e.value)
    assert f"{tmp_path / 'orennayar.rdsl'}:" in str(e.value)
    path = scene(tmp_path, '<bsdf type="orennayar">\n    <string name="sigma" value="x"/>'
                 '\n</bsdf>', "s2.xml")
    with pytest.raises(SceneError, match="is a string"):
        load_scene_description(path)


def test_missing_parameter_takes_the_declared_default_or_is_required(tmp_path):
    src = (EXAMPLES / "orennayar.rdsl").read_text()
    (tmp_path / "orennayar.rdsl").write_text(src)
    desc = load_scene_description(scene(tmp_path, '<bsdf type="orennayar"/>'))
    from rdsl.runtime.render.bsdfs import bsdf_instance
    assert bsdf_instance(desc.shapes[0].bsdf).params == {}  # specialize takes the defaults
    (tmp_path / "orennayar.rdsl").write_text(src.replace("param sigma: Float = 20.0;",
                                                         "param sigma: Float;"))
    registry._checked.cache_clear()
    with pytest.raises(SceneError, match="missing the required parameter 'sigma'"):
        load_scene_description(scene(tmp_path, '<bsdf type="orennayar"/>', "s2.xml"))


def test_two_plugins_with_one_name_in_one_folder(tmp_path):
    src = renamed("bsdf/diffuse.rdsl", "diffuse", "twin")
    (tmp_path / "a.rdsl").write_text(src)
    (tmp_path / "b.rdsl").write_text(src)
    with pytest.raises(CompileError) as e:
        load_scene_description(scene(tmp_path, '<bsdf type="twin"/>'))
    assert str(tmp_path / "a.rdsl") in str(e.value) and str(tmp_path / "b.rdsl") in str(e.value)
    assert "two bsdf plugins named `twin`" in str(e.value)


# ---------------------------------------------------------------------------- the examples

ORENNAYAR = EXAMPLES / "orennayar.rdsl"


def oren_nayar_np(wi: np.ndarray, wo: np.ndarray, r: float, sigma: float) -> np.ndarray:
    """f cos(theta_o) of PBRT's OrenNayar::f, in float64 (an independent implementation)."""
    s2 = np.radians(sigma) ** 2
    a, b = 1 - s2 / (2 * (s2 + 0.33)), 0.45 * s2 / (s2 + 0.09)
    ti, to = np.arccos(wi[:, 2]), np.arccos(wo[:, 2])
    dphi = np.cos(np.arctan2(wi[:, 1], wi[:, 0]) - np.arctan2(wo[:, 1], wo[:, 0]))
    alpha, beta = np.maximum(ti, to), np.minimum(ti, to)
    f = r / np.pi * (a + b * np.maximum(0, dphi) * np.sin(alpha) * np.tan(beta))
    return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), f * wo[:, 2], 0.0)


def hemisphere(n: int, seed: int) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 1e-3
    return (v / np.linalg.norm(v, axis=1, keepdims=True)).astype(f32)


def surface(wi: np.ndarray) -> dict:
    n = len(wi)
    z = np.tile(f32([0, 0, 1]), (n, 1))
    return {"p": np.zeros((n, 3), f32), "n": z, "sh_n": z, "uv": np.zeros((n, 2), f32),
            "wi": np.ascontiguousarray(wi, f32), "t": np.ones(n, f32), "valid": np.ones(n, bool)}


@pytest.fixture(scope="module")
def oren():
    return Harness(variant="rgb", decl=next(d for d in declarations(ORENNAYAR) if d.name == "orennayar"))


@pytest.mark.parametrize("sigma", [10.0, 35.0])
def test_orennayar_matches_pbrt_and_samples_its_pdf(oren, sigma):
    wi, wo = hemisphere(4000, 1), hemisphere(4000, 2)
    got = oren.eval(surface(wi), wo, reflectance=0.6, sigma=sigma)
    np.testing.assert_allclose(got[:, 0], oren_nayar_np(wi.astype(np.float64),
                                                        wo.astype(np.float64), 0.6, sigma),
                               rtol=2e-4, atol=1e-6)
    n = 400_000
    rng = np.random.default_rng(7)
    for theta in (0.3, 1.2):
        w = np.tile(f32([np.sin(theta), 0.0, np.cos(theta)]), (n, 1))
        bs = oren.sample(surface(w), rng.random(n).astype(f32), rng.random((n, 2)).astype(f32),
                         reflectance=0.6, sigma=sigma)
        valid = bs["pdf"] > 0

        def pdf(d, w0=w[0]):
            return np.asarray(oren.pdf(surface(np.tile(w0, (len(d), 1))),
                                       np.ascontiguousarray(d, f32), reflectance=0.6,
                                       sigma=sigma), np.float64)

        assert chi2_directions(bs["wo"], valid, pdf, n) > 1e-3
        # weight = eval / pdf, and the albedo (the mean weight) is at most 1
        k = np.flatnonzero(valid)[:2000]
        e = oren.eval(surface(w[k]), bs["wo"][k], reflectance=0.6, sigma=sigma)
        np.testing.assert_allclose(bs["weight"][k, 0], e[:, 0] / bs["pdf"][k], rtol=1e-4)
        assert bs["weight"][valid, 0].mean() <= 1.0


def test_orennayar_at_sigma_0_is_lambert(oren):
    lam = Harness("diffuse", "rgb")
    wi, wo = hemisphere(3000, 3), hemisphere(3000, 4)
    u1, u2 = np.random.default_rng(5).random(3000).astype(f32), \
        np.random.default_rng(6).random((3000, 2)).astype(f32)
    si = surface(wi)
    np.testing.assert_array_equal(oren.eval(si, wo, reflectance=0.7, sigma=0.0),
                                  lam.eval(si, wo, reflectance=0.7))
    np.testing.assert_array_equal(oren.pdf(si, wo, sigma=0.0), lam.pdf(si, wo))
    a = oren.sample(si, u1, u2, reflectance=0.7, sigma=0.0)
    b = lam.sample(si, u1, u2, reflectance=0.7)
    for key in ("wo", "pdf", "weight"):
        np.testing.assert_array_equal(a[key], b[key])


def test_wood_texture_range():
    mod = rdsl.jit(EXAMPLES / "wood.rdsl", target="host")
    uv = np.random.default_rng(9).uniform(-20, 20, (20000, 2)).astype(f32)
    n = len(uv)
    z = np.zeros((n, 3), f32)
    si = {"p": z, "n": z, "sh_n": z, "uv": uv, "wi": np.tile(f32([0, 0, 1]), (n, 1)),
          "t": np.ones(n, f32), "valid": np.ones(n, bool)}
    t = np.asarray(mod["wood.eval_1"](si))
    assert t.min() >= 0.0 and t.max() <= 1.0 and t.std() > 0.2  # rings: both extremes
    c = np.asarray(mod["wood.eval"](si, early=(1.0, 1.0, 1.0), late=(0.0, 0.0, 0.0)))
    assert c.min() >= 0.0 and c.max() <= 1.0
    np.testing.assert_allclose(c[:, 0], 1.0 - t, atol=1e-6)


def test_examples_render_from_the_command_line(tmp_path):
    for name in ("orennayar", "wood"):
        out = tmp_path / f"{name}.exr"
        r = subprocess.run([sys.executable, "-m", "rdsl.cli", "render",
                            str(EXAMPLES / f"{name}.xml"), "-o", str(out), "-D", "res=8",
                            "-D", "spp=1", "--quiet"], capture_output=True, text=True,
                           check=False)
        assert r.returncode == 0, r.stderr
        assert out.is_file()
