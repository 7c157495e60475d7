"""Parsing ahead in a forked helper (dsl/parse_ahead.py): with an empty parse cache the
loader parses only part of a program's files itself, reads the rest from the helper's
cache entries, and ends with the same ASTs and the same diagnostics as without it."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rdsl.compiler.diagnostics import CompileError
from rdsl.dsl import imports, parse_ahead, parser

ROOT = Path(__file__).resolve().parents[1]
PATH_TRACER = imports.STDLIB / "integrator" / "path.rdsl"

pytestmark = pytest.mark.skipif(not hasattr(os, "fork") or (os.cpu_count() or 1) < 2,
                                reason="parsing ahead needs os.fork and two CPUs")


def _dirs(importer: str) -> list[Path]:
    return imports.import_dirs(importer, [])  # no search paths, as load_program's default


@pytest.fixture
def empty_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(parser, "_ASTS", {})  # nothing parsed in this process either
    return tmp_path / "cache"


def _load(path: Path, monkeypatch: pytest.MonkeyPatch, ahead: bool) -> tuple[list, list]:
    """The loaded modules of ``path`` and the files this process parsed itself."""
    monkeypatch.setenv(parse_ahead.ENV, "1" if ahead else "0")
    own: list[str] = []
    real = parser._parse

    def counting(source: str, filename: str):
        own.append(Path(filename).name)
        return real(source, filename)

    monkeypatch.setattr(parser, "_parse", counting)
    return imports.load_program(path.read_text(), str(path), path=path), own


def test_the_plan_is_what_the_loader_loads(empty_cache: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    plan = parse_ahead.planned_files(PATH_TRACER.read_text(), str(PATH_TRACER),
                                     imports.prelude(), _dirs)
    mods, own = _load(PATH_TRACER, monkeypatch, ahead=False)
    planned = [Path(name).resolve() for _, name in plan]
    assert sorted(planned) == sorted(Path(m.key).resolve() for m in mods)
    # and in the loader's order of parsing (depth first, each file before its imports)
    assert [p.name for p in planned] == own
    assert len(own) > 2 * parse_ahead.MIN_FILES


def test_the_helper_parses_part_and_the_asts_are_the_same(
        empty_cache: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    alone, own_alone = _load(PATH_TRACER, monkeypatch, ahead=False)

    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "other"))
    monkeypatch.setattr(parser, "_ASTS", {})
    helped, own_helped = _load(PATH_TRACER, monkeypatch, ahead=True)
    # the helper parsed from the end: the loader read some of its files from the cache
    assert len(own_helped) < len(own_alone)
    assert own_helped == own_alone[:len(own_helped)]
    assert [m.key for m in helped] == [m.key for m in alone]
    for a, b in zip(alone, helped):
        assert a.program == b.program, a.key  # dataclasses: field by field
    entries = sorted((tmp_path / "other" / "ast").iterdir())
    assert not [e for e in entries if e.suffix == ".tmp"]  # no half-written entry left
    # the helper ended with the load: nothing of it runs or writes afterwards
    assert parse_ahead._children == []
    time.sleep(0.3)
    assert sorted((tmp_path / "other" / "ast").iterdir()) == entries


def test_a_syntax_error_is_reported_as_without_it(empty_cache: Path,
                                                   monkeypatch: pytest.MonkeyPatch,
                                                   tmp_path: Path) -> None:
    lib = tmp_path / "lib"
    lib.mkdir()
    for k in range(6):  # enough files to fork for, the last imported one broken
        body = f"import m{k + 1};\n" if k < 5 else "fn broken( -> Float { return 1.0; }\n"
        (lib / f"m{k}.rdsl").write_text(body + f"fn f{k}(x: Float) -> Float {{ return x; }}\n")
    main = lib / "m0.rdsl"
    messages = []
    for ahead in (False, True):
        monkeypatch.setattr(parser, "_ASTS", {})
        monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / f"cache{ahead}"))
        with pytest.raises(CompileError) as e:
            _load(main, monkeypatch, ahead)
        messages.append(str(e.value))
    assert messages[0] == messages[1]
    assert "m5.rdsl:1" in messages[0]


def test_the_helper_keeps_no_output_pipe_open(tmp_path: Path) -> None:
    """A caller that reads a command's output to its end gets it when the command ends:
    the helper's standard streams are /dev/null and it holds no other descriptor of its
    parent's but its pipe (read while it is still parsing: a whole program's files)."""
    env = dict(os.environ, RDSL_CACHE_DIR=str(tmp_path / "cache"), RDSL_PARSE_AHEAD="1")
    code = ("import os, sys, time; from pathlib import Path; from rdsl.dsl import imports, "
            "parse_ahead; p = Path(sys.argv[1]); h = parse_ahead.start(p.read_text(), "
            "str(p), imports.prelude(), lambda i: imports.import_dirs(i, [])); time.sleep(0.05); "
            "d = f'/proc/{h.pid}/fd'; "
            "print(sorted((int(f), os.readlink(f'{d}/{f}')) for f in os.listdir(d)))")
    if not Path("/proc/self/fd").is_dir():
        pytest.skip("no /proc to list the helper's descriptors")
    out = subprocess.run([sys.executable, "-c", code, str(PATH_TRACER)], env=env,
                         capture_output=True, text=True, timeout=120, check=True)
    fds = eval(out.stdout)  # noqa: S307 - the list the child printed
    assert [target for fd, target in fds if fd <= 2] == [os.devnull] * 3
    others = [target for fd, target in fds if fd > 2]
    assert len(others) == 1 and others[0].startswith("pipe:"), fds


def test_off_by_the_environment(empty_cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(parse_ahead.ENV, "0")
    assert parse_ahead.start(PATH_TRACER.read_text(), str(PATH_TRACER), imports.prelude(),
                             _dirs) is None
    monkeypatch.setenv(parse_ahead.ENV, "1")
    helper = parse_ahead.start(PATH_TRACER.read_text(), str(PATH_TRACER), imports.prelude(),
                               _dirs)
    assert helper is not None
    helper.stop()
