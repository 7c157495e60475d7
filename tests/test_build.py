"""One :class:`Build` per entry point: target and variant names become a Target and a
ColorModel at once, a bad name is a diagnostic listing the valid ones before any file is
read, and the colour models answer what the compiler and the runtime ask of a variant."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest
import rdsl
from rdsl.compiler.build import Build, color_model
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.targets import TARGETS, host_target
from rdsl.core.color import (
    MODELS,
    MONO,
    MONO_POLARIZED,
    RGB,
    SPECTRAL,
    SPECTRAL_POLARIZED,
    VARIANTS,
    ColorModel,
)

ROOT = Path(__file__).resolve().parent.parent
ALL_VARIANTS = "mono, rgb, spectral, mono_polarized, spectral_polarized"
SRC = "fn f(x: Float) -> Float { return x + 1.0; }\n"


# ------------------------------------------------------------------ Build.of


@pytest.mark.parametrize("target", [*TARGETS, "host"])
@pytest.mark.parametrize("variant", VARIANTS)
def test_build_of_every_name(target: str, variant: str):
    b = Build.of(target=target, variant=variant)
    want = host_target() if target == "host" else TARGETS[target]
    assert b.target == want and b.width == want.width
    assert b.model is MODELS[variant] and b.model.name == variant


def test_build_defaults_and_objects_pass_through():
    assert Build.of() == Build(host_target(), RGB)
    b = Build.of(TARGETS["avx2"], SPECTRAL)
    assert b.target is TARGETS["avx2"] and b.model is SPECTRAL
    assert Build.of("sse4", "mono") == Build.of(TARGETS["sse4"], MONO)  # frozen, by value
    with pytest.raises(AttributeError):
        b.model = RGB  # type: ignore[misc]


@pytest.mark.parametrize("bad", ["rgbx", "RGB", "", "spectral_", "polarized"])
def test_a_bad_variant_lists_the_valid_ones(bad: str):
    with pytest.raises(CompileError, match=f"unknown variant `{bad}`") as e:
        Build.of("scalar", bad)
    assert f"valid variants: {ALL_VARIANTS}" in str(e.value)
    with pytest.raises(CompileError, match=ALL_VARIANTS):
        color_model(bad)


def test_a_bad_target_lists_the_valid_ones():
    with pytest.raises(CompileError, match="unknown target `neon`.*scalar, sse4, avx2, "
                                           "avx512, host"):
        Build.of("neon", "rgb")


# ------------------------------------------------------------------ colour models

# name: (n, polarized, spectral, mono, film channels, traits)
PROPERTIES = {
    "mono": (1, False, False, True, 1, {"mono"}),
    "rgb": (3, False, False, False, 3, {"rgb"}),
    "spectral": (4, False, True, False, 3, {"spectral"}),
    "mono_polarized": (1, True, False, True, 1, {"mono", "polarized"}),
    "spectral_polarized": (4, True, True, False, 3, {"spectral", "polarized"}),
}


@pytest.mark.parametrize("name", VARIANTS)
def test_model_properties(name: str):
    m = MODELS[name]
    assert m.name == name
    assert (m.n, m.polarized, m.spectral, m.mono, m.channels, set(m.traits)) == \
        PROPERTIES[name]


def test_model_table():
    assert VARIANTS == tuple(PROPERTIES)
    assert [MONO, RGB, SPECTRAL, MONO_POLARIZED, SPECTRAL_POLARIZED] == list(MODELS.values())
    assert all(isinstance(m, ColorModel) for m in MODELS.values())


def test_core_imports_nothing_else_from_rdsl():
    """core/ is shared by the compiler and the runtime: it may import only itself."""
    for path in (ROOT / "core").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                outside = node.level > 1 or (node.level == 0 and (node.module or "")
                                             .startswith("rdsl") and not
                                             (node.module or "").startswith("rdsl.core"))
                assert not outside, f"{path.name}:{node.lineno} imports {node.module}"
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    assert alias.name == "rdsl.core" or not alias.name.startswith("rdsl"), \
                        f"{path.name}:{node.lineno} imports {alias.name}"


# ------------------------------------------------------------------ entry points fail early


def test_load_scene_checks_names_before_reading_the_scene(tmp_path: Path, monkeypatch):
    from rdsl.runtime.render import renderer

    def never(*args, **kwargs):
        raise AssertionError("the scene was read before its build was checked")

    monkeypatch.setattr(renderer, "load_scene_description", never)
    missing = tmp_path / "no_such_scene.xml"
    with pytest.raises(CompileError, match=f"unknown variant `rgbx`.*{ALL_VARIANTS}"):
        rdsl.load_scene(missing, variant="rgbx")
    with pytest.raises(CompileError, match="unknown target `avx1024`"):
        rdsl.load_scene(missing, target="avx1024")


def test_jit_checks_names_before_reading_the_source(tmp_path: Path):
    missing = tmp_path / "missing.rdsl"
    with pytest.raises(CompileError, match="unknown variant `rgbx`"):
        rdsl.jit(missing, target="scalar", variant="rgbx")
    with pytest.raises(CompileError, match="unknown target `avx1024`"):
        rdsl.jit(missing, target="avx1024")


@pytest.mark.parametrize("cmd", ["render", "ir", "compile"])
def test_cli_reports_a_bad_variant_before_reading_its_input(cmd: str, tmp_path: Path,
                                                          capsys):
    from rdsl.cli import main

    missing = tmp_path / ("scene.xml" if cmd == "render" else "kernel.rdsl")
    assert main([cmd, str(missing), "--variant", "rgbx"]) == 1
    err = capsys.readouterr().err
    assert f"unknown variant `rgbx` (valid variants: {ALL_VARIANTS})" in err
    assert "no such" not in err and "Traceback" not in err


def test_cli_render_reports_a_bad_target(tmp_path: Path, capsys):
    from rdsl.cli import main

    assert main(["render", str(tmp_path / "scene.xml"), "--target", "avx1024"]) == 1
    err = capsys.readouterr().err
    assert "unknown target `avx1024`" in err and "no such" not in err


# ------------------------------------------------------------------ builds downstream


def test_jit_takes_a_build_and_the_module_knows_its_model(tmp_path: Path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    by_name = rdsl.jit(SRC, target="scalar", variant="mono")
    by_build = rdsl.jit(SRC, build=Build.of("scalar", MONO))
    assert not by_name.from_cache and by_build.from_cache  # the same build, the same key
    assert by_build.model is MONO and by_build.variant == "mono"
    assert not rdsl.jit(SRC, build=Build.of("scalar", "spectral")).from_cache


def test_cache_key_follows_the_build():
    from rdsl.runtime.cache import cache_key

    def key(target: str, variant: str) -> str:
        return cache_key(SRC, [], Build.of(target, variant), {})

    assert key("scalar", "rgb") == key("scalar", "rgb")
    assert len({key("scalar", "rgb"), key("scalar", "mono"), key("sse4", "rgb")}) == 3


def test_a_manifest_naming_an_unknown_variant_is_refused(tmp_path: Path):
    (tmp_path / "k.so").write_bytes(b"")
    (tmp_path / "k.json").write_text(json.dumps(
        {"target": "scalar", "width": 1, "variant": "cmyk", "kernels": []}))
    with pytest.raises(CompileError, match="not a valid rdsl manifest.*unknown variant `cmyk`"):
        rdsl.load(tmp_path / "k.so")


def test_pipeline_lifts_to_the_builds_model():
    from rdsl.compiler.driver import frontend, pipeline, run_passes

    for variant in VARIANTS:
        m = frontend(SRC)
        run_passes(m, pipeline(Build.of("scalar", variant)), stop_after="lift")
        assert m.attrs["variant"] == variant
