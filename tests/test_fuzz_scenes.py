"""Mutation fuzzing of scene files: a mangled scene loads, or gives one clear error.

Valid scenes of the repository (the Cornell box, the material scene, the compatibility
scenes, the plugin examples) get one or two random edits with a fixed seed: an attribute
deleted, a value replaced by a wrong one (text, empty, an overflowing or non-finite number,
too many numbers, binary garbage), a plugin type renamed to an unknown one, a line deleted or
duplicated, the file truncated, bytes of garbage inserted, an id broken, a property tag
swapped for another.  Loading each must either succeed or raise :class:`CompileError`
whose message names the mutated file and a line; any other exception is a loader bug, and a
load may not take more than a few seconds (no hang).  Every mutated scene lives in its own
temporary folder beside links to its source folder's files, so a scene that writes nothing
can be told from one that writes: the folder must hold nothing new afterwards.
"""

from __future__ import annotations

import random
import re
import signal
import warnings
from pathlib import Path

import pytest

import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.runtime.render.renderer import load_scene

pytest.importorskip("rdsl.runtime.embree")

ROOT = Path(rdsl.__file__).parent
CORPUS = sorted([ROOT / "examples/cbox/cbox.xml", ROOT / "bench/scenes/materials.xml",
                 ROOT / "docs/walkthrough.xml", *(ROOT / "bench/scenes/compat").glob("*.xml"),
                 *(ROOT / "examples/plugins").glob("*.xml")])
BAD_VALUES = ["abc", "", "1e99999", "nan", "-inf", "-1", "0", "1e40", "1, 2", "1,2,3,4,5",
              "true", "\x00", "é", "999999999999", "../../../etc/passwd", "$undefined"]
TAGS = ["float", "rgb", "string", "integer", "boolean", "point", "texture", "bsdf",
        "spectrum", "ref", "transform"]
ATTR = re.compile(r'(\w+)="([^"]*)"')
SECONDS_PER_LOAD = 30  # generous for a loaded CI machine; a load takes well under one


def _pick(rng: random.Random, pattern: str, text: str) -> re.Match | None:
    found = list(re.finditer(pattern, text))
    return rng.choice(found) if found else None


def _splice(text: str, m: re.Match | None, group: int, new: str) -> str:
    return text if m is None else text[:m.start(group)] + new + text[m.end(group):]


def mutate(text: str, rng: random.Random) -> str:
    """``text`` with one random edit (see the module docstring)."""
    lines = text.splitlines(True)
    i = rng.randrange(len(lines))
    kind = rng.randrange(9)
    if kind == 0:
        return _splice(text, _pick(rng, ATTR.pattern, text), 0, "")
    if kind == 1:
        return _splice(text, _pick(rng, ATTR.pattern, text), 2, rng.choice(BAD_VALUES))
    if kind == 2:
        return _splice(text, _pick(rng, r'type="(\w+)"', text), 1, "nosuch")
    if kind == 3:
        return "".join(lines[:i] + lines[i + 1:])
    if kind == 4:
        return "".join(lines[:i + 1] + lines[i:])
    if kind == 5:
        return text[:rng.randrange(len(text))]
    if kind == 6:
        k = rng.randrange(len(text))
        return text[:k] + bytes(rng.randrange(256) for _ in range(8)).decode("latin-1") + text[k:]
    if kind == 7:
        return _splice(text, _pick(rng, r'id="([^"]*)"', text), 1, "zz")
    return _splice(text, _pick(rng, r"<(%s)\b" % "|".join(TAGS), text), 1, rng.choice(TAGS))


class _Timeout(Exception):
    pass


def _alarm(signum, frame):  # noqa: ARG001 - signal handler signature
    raise _Timeout


def _load(path: Path) -> str | None:
    """Load ``path``: None if it loads or fails well, else what went wrong."""
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(SECONDS_PER_LOAD)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            load_scene(path, specialize=False)
    except CompileError as e:
        msg = str(e)
        if path.name not in msg or not re.search(re.escape(path.name) + r":\d+", msg):
            return f"error without file:line: {msg[:300]}"
    except _Timeout:
        return f"no answer within {SECONDS_PER_LOAD} s"
    except Exception as e:  # noqa: BLE001 - any other exception is the bug we look for
        return f"{type(e).__name__}: {e}"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    return None


@pytest.mark.parametrize("seed", range(4))
def test_mutated_scenes_load_or_fail_with_a_location(tmp_path: Path, seed: int) -> None:
    rng = random.Random(1000 + seed)
    failures = []
    for case in range(40):
        src = rng.choice(CORPUS)
        folder = tmp_path / f"case{case}"
        folder.mkdir()
        for f in src.parent.iterdir():
            if f.name != src.name:
                (folder / f.name).symlink_to(f)
        text = src.read_text()
        for _ in range(rng.randrange(1, 3)):
            text = mutate(text, rng)
        path = folder / src.name
        path.write_bytes(text.encode("utf-8", "replace"))
        before = sorted(p.name for p in folder.iterdir())
        problem = _load(path)
        if problem:
            failures.append(f"{src.name} (case {case}): {problem}")
        assert sorted(p.name for p in folder.iterdir()) == before, f"case {case} wrote files"
    assert not failures, "\n".join(failures)


def test_the_corpus_itself_loads() -> None:
    """The mutations start from scenes that load (else every case would be an error)."""
    assert len(CORPUS) >= 10
    for path in CORPUS:
        assert _load(path) is None, path


@pytest.mark.parametrize("scale", ["1e30\"/><scale value=\"1e30", "nan"])
def test_a_transform_that_overflows_float32_is_an_error_at_its_line(tmp_path: Path,
                                                                   scale: str) -> None:
    """(The fuzzer found it: the vertices reached Embree as inf and a ValueError came back.)"""
    path = tmp_path / "big.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="rectangle">\n'
                    f'  <transform name="to_world"><scale value="{scale}"/></transform>\n'
                    '</shape>\n</scene>\n')
    with pytest.raises(CompileError, match=r"big\.xml:3:.*not finite"):
        load_scene(path)
