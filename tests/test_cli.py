"""The `rdsl` command line: good input works, bad input gets one clear diagnostic, exit
status 1 and never a traceback."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from rdsl.compiler.targets import get_target, host_supports

ROOT = Path(__file__).resolve().parent.parent
GOOD = "fn lerp(a: Float, b: Float, t: Float) -> Float { return a + (b - a) * t; }\n"


def rdsl(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    return subprocess.run([sys.executable, "-m", "rdsl.cli", *args], cwd=cwd,
                          capture_output=True, text=True, env=env, timeout=300)


@pytest.fixture
def good(tmp_path: Path) -> Path:
    p = tmp_path / "lerp.rdsl"
    p.write_text(GOOD)
    return p


def _bad(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.rdsl"
    p.write_text(text)
    return p


def assert_user_error(r: subprocess.CompletedProcess, *needles: str) -> None:
    assert r.returncode == 1, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout
    for n in needles:
        assert n in r.stderr, f"{n!r} not in {r.stderr!r}"


def test_check_ok(good: Path):
    r = rdsl("check", str(good))
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout


def test_ir_print_after_every_pass(good: Path):
    for name in ("lower", "inline", "lift", "scalarize", "vectorize", "optimize"):
        r = rdsl("ir", str(good), "--target", "sse4", "--print-after", name)
        assert r.returncode == 0, r.stderr
        assert "func @lerp" in r.stdout
    r = rdsl("ir", str(good), "--target", "sse4", "--print-after", "vectorize")
    assert "f32x4" in r.stdout and "mask" in r.stdout


def test_compile_writes_library_header_manifest(good: Path, tmp_path: Path):
    out = tmp_path / "build" / "lerp"
    r = rdsl("compile", str(good), "--target", "scalar", "-o", str(out))
    assert r.returncode == 0, r.stderr
    for ext in (".so", ".h", ".json"):
        assert out.with_suffix(ext).is_file()
    manifest = json.loads(out.with_suffix(".json").read_text())
    assert manifest["target"] == "scalar" and manifest["variant"] == "rgb"
    assert [k["name"] for k in manifest["kernels"]] == ["lerp"]
    assert "rdsl_version" in manifest
    assert "rdsl_lerp" in out.with_suffix(".h").read_text()


@pytest.mark.skipif(not host_supports(get_target("avx512")), reason="CPU lacks AVX-512")
def test_avx512_asm_has_zmm(good: Path):
    r = rdsl("compile", str(good), "--target", "avx512", "--emit", "asm")
    assert r.returncode == 0, r.stderr
    assert "zmm" in r.stdout


def test_emit_llvm(good: Path):
    r = rdsl("compile", str(good), "--target", "avx2", "--emit", "llvm")
    assert r.returncode == 0, r.stderr
    assert "<8 x float>" in r.stdout


def test_malformed_source(tmp_path: Path):
    p = _bad(tmp_path, "fn f(x: Float) -> Float {\n    return x +;\n}\n")
    r = rdsl("check", str(p))
    assert_user_error(r, f"{p}:2:", "error:")


def test_unknown_identifier(tmp_path: Path):
    p = _bad(tmp_path, "fn f(x: Float) -> Float {\n    return y;\n}\n")
    assert_user_error(rdsl("compile", str(p), "--target", "scalar"), f"{p}:2:12", "`y`")


def test_type_error(tmp_path: Path):
    p = _bad(tmp_path, "fn f(x: Float) -> Float {\n    return x + true;\n}\n")
    assert_user_error(rdsl("check", str(p)), f"{p}:2:")


def test_recursion(tmp_path: Path):
    p = _bad(tmp_path, "fn f(x: Float) -> Float {\n    return g(x);\n}\n"
                       "fn g(x: Float) -> Float {\n    return f(x) + 1.0;\n}\n")
    assert_user_error(rdsl("compile", str(p), "--target", "scalar", "-o",
                           str(tmp_path / "o")), "recursion")


def test_plugin_missing_interface_function(tmp_path: Path):
    p = _bad(tmp_path, "bsdf half {\n    fn eval(si: Surface, wo: Vec3) -> Spectrum {\n"
                       "        return Spectrum(1.0);\n    }\n}\n")
    assert_user_error(rdsl("check", str(p)), f"{p}:1:", "pdf")


def test_wrong_target(good: Path):
    assert_user_error(rdsl("compile", str(good), "--target", "avx1024"), "avx1024", "avx512")


def test_wrong_variant(good: Path):
    assert_user_error(rdsl("ir", str(good), "--variant", "hyperspectral"), "hyperspectral",
                      "rgb")


def test_unwritable_output(good: Path, tmp_path: Path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert_user_error(rdsl("compile", str(good), "--target", "scalar", "-o",
                           str(blocker / "sub" / "out")), "file")
    assert blocker.read_text() == "not a folder"


def test_never_overwrites_input(tmp_path: Path):
    p = tmp_path / "k.ll"
    p.write_text(GOOD)
    src = tmp_path / "k.rdsl"
    src.write_text(GOOD)
    r = rdsl("compile", str(src), "--emit", "llvm", "-o", str(src))
    assert_user_error(r, "overwrite")
    assert src.read_text() == GOOD


def test_missing_file(tmp_path: Path):
    assert_user_error(rdsl("check", str(tmp_path / "nope.rdsl")), "no such file")


@pytest.mark.parametrize("command", ["render", "bench"])
@pytest.mark.parametrize("threads", ["0", "-2", "two"])
def test_thread_count_is_checked(command: str, threads: str, tmp_path: Path):
    """``--threads`` below 1 or not a number is a usage error naming the value, before any
    scene is read (the kernel call refuses it with a traceback's ValueError)."""
    r = rdsl(command, str(tmp_path / "missing.xml"), "--threads", threads)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert f"argument --threads: expected a number of threads, 1 or more, got `{threads}`" \
        in r.stderr


@pytest.mark.parametrize("flag,value,expected", [
    ("--spp", "0", "expected a number of samples per pixel, 1 or more, got `0`"),
    ("--spp", "-3", "expected a number of samples per pixel, 1 or more, got `-3`"),
    ("--spp", "2.5", "expected a number of samples per pixel, 1 or more, got `2.5`"),
    ("--seed", "-1", "expected a whole number in 0 .. 4294967295, got `-1`"),
    ("--seed", "4294967296", "expected a whole number in 0 .. 4294967295, got `4294967296`"),
])
def test_sample_count_and_seed_are_checked(flag: str, value: str, expected: str,
                                           tmp_path: Path):
    """A count below 1 rendered a black image (and wrote it over the last one) and 0 meant
    the scene's count; a negative seed failed in numpy with a traceback.  Both are usage
    errors now, before any scene is read, and nothing is written."""
    r = rdsl("render", str(tmp_path / "missing.xml"), flag, value, cwd=tmp_path)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert f"argument {flag}: {expected}" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["render", "bench"])
def test_a_folder_is_not_a_scene(command: str, tmp_path: Path):
    r = rdsl(command, str(tmp_path))
    assert_user_error(r, f"{tmp_path}: is a folder; expected a Mitsuba 3 XML scene file")
