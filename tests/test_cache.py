"""The kernel cache end to end (real compiler): a second load does not recompile, and an
edit to an imported file does."""

from __future__ import annotations

import numpy as np

import rdsl


def test_second_load_is_cached_and_imports_are_keyed(tmp_path, monkeypatch):
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    lib = tmp_path / "helper.rdsl"
    lib.write_text("fn twice(x: Float) -> Float { return 2.0 * x; }\n")
    main = tmp_path / "main.rdsl"
    main.write_text("import helper;\nfn f(x: Float) -> Float { return twice(x) + 1.0; }\n")
    x = np.arange(5, dtype=np.float32)

    first = rdsl.jit(main, target="scalar")
    second = rdsl.jit(main, target="scalar")
    assert not first.from_cache and second.from_cache
    # a cache hit costs a hash and a dlopen, not a compile
    assert second.compile_seconds < first.compile_seconds / 5
    np.testing.assert_array_equal(second.f(x), 2 * x + 1)

    lib.write_text("fn twice(x: Float) -> Float { return 3.0 * x; }\n")
    third = rdsl.jit(main, target="scalar")
    assert not third.from_cache
    np.testing.assert_array_equal(third.f(x), 3 * x + 1)


def test_source_text_under_another_file_name_is_a_hit(tmp_path, monkeypatch):
    """The `filename` option only labels diagnostics: the same kernels compiled for a scene
    copied elsewhere load from the cache (each test's tmp_path would recompile otherwise),
    while other options still miss."""
    monkeypatch.setenv("RDSL_CACHE_DIR", str(tmp_path / "cache"))
    src = "fn f(x: Float) -> Float { return x * x; }\n"
    first = rdsl.jit(src, target="scalar", filename=str(tmp_path / "a" / "scene.rdsl"))
    second = rdsl.jit(src, target="scalar", filename=str(tmp_path / "b" / "scene.rdsl"))
    other = rdsl.jit(src, target="scalar", variant="mono", filename="scene.rdsl")
    assert not first.from_cache and second.from_cache and not other.from_cache
    x = np.arange(4, dtype=np.float32)
    np.testing.assert_array_equal(second.f(x), x * x)
