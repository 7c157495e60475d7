"""One rule for "is this a file or source text?" (compiler/sources.py), the same at every
entry point: the frontend's ``check``, ``rdsl.jit`` and the kernel cache's file list."""

from __future__ import annotations

from pathlib import Path

import pytest
import rdsl
from rdsl.compiler.diagnostics import CompileError
from rdsl.compiler.sources import is_path, read_source, source_files
from rdsl.dsl import check

SRC = "fn twice(x: Float) -> Float { return 2.0 * x; }"


def test_the_rule(tmp_path: Path):
    f = tmp_path / "k.txt"
    f.write_text(SRC)
    assert is_path(f) and is_path(str(f))  # an existing file, whatever its suffix
    assert is_path("missing.rdsl") and is_path(Path("missing.txt"))
    assert not is_path(SRC) and not is_path("missing.txt")
    assert not is_path(SRC + "\n// x.rdsl") and not is_path("x" * 5000 + ".rdsl")
    assert read_source(SRC) == (SRC, None)
    assert read_source(str(f)) == (SRC, f)
    # the cache keys a file by the files it imports, source text by the prelude alone
    prelude = source_files(SRC)
    g = tmp_path / "imports.rdsl"
    g.write_text("import warp;\n" + SRC)
    files = source_files(g)
    assert files[0] == g.resolve() and any(p.name == "warp.rdsl" for p in files)
    assert all(p.parent.name == "stdlib" for p in prelude) and len(prelude) == 3


@pytest.mark.parametrize("entry", ["check", "jit"])
def test_a_missing_rdsl_file_is_named_at_every_entry_point(entry, tmp_path: Path):
    missing = str(tmp_path / "missing.rdsl")
    run = {"check": check, "jit": lambda p: rdsl.jit(p, target="scalar")}[entry]
    with pytest.raises(CompileError, match=r"cannot read `.*missing\.rdsl`"):
        run(missing)


def test_source_text_compiles_the_same_as_its_file(tmp_path: Path):
    import numpy as np

    f = tmp_path / "twice.rdsl"
    f.write_text(SRC)
    x = np.arange(5, dtype=np.float32)
    for m in (rdsl.jit(SRC, target="scalar"), rdsl.jit(f, target="scalar"),
              rdsl.jit(str(f), target="scalar")):
        np.testing.assert_array_equal(m.twice(x), 2 * x)
