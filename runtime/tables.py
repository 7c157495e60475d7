"""Filling the generic build's tables at scene load.

A plugin's ``table`` functions (docs/language.md, "Tables") are computed once per scene.  The
specialized build folds them into its code at compile time; the generic build, whose code
does not depend on parameter values, reserves room for them at the end of ``PRM`` and lists
them in its manifest (``tables``: the table function, its sampling, the instance, the offset).
:func:`fill_tables` computes them for the scene's values with the same compiled table
kernels (:func:`rdsl.compiler.precompute.tabulate`) and returns the complete ``PRM``.

Computing them needs the plugins' IR (the frontend over the kernel's whole source: 0.3 s),
so each table's samples are kept on disk too, keyed by the generic kernels' cache entry
(which hashes every source they were built from) and by the instance's plain values (those
a table may depend on): a scene rendered again with other colours, the generic build
standing in (runtime/render/stand_in.py), fills its tables without the frontend.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np

from ..core.scene_spec import SceneSpec

_ir: dict[tuple[str, str | None, tuple[str, ...]], Any] = {}  # source -> its lowered IR
_samples: dict[tuple[Any, ...], np.ndarray] = {}  # (source, table, values) -> the samples
_lock = threading.Lock()


def fill_tables(mod: Any, scene: SceneSpec, prm: np.ndarray, source: str | Path,
                filename: str | None = None, search_paths: Any = ()) -> np.ndarray:
    """``prm`` extended with the tables ``mod`` (a generic build of ``source``) reads, for
    the parameter values of ``scene`` (the scene as given, not its slots); ``prm`` itself
    when the build reads none."""
    entries = (mod.manifest or {}).get("tables") or []
    if not entries:
        return prm
    from ..compiler.precompute import (load_samples, store_samples, table_params, table_size,
                                       tabulate)

    size = max(int(e["offset"]) + table_size(e) for e in entries)
    out = np.zeros(max(size, len(prm), 1), np.float32)
    out[:len(prm)] = prm
    files = [_samples_file(mod, e, getattr(scene, e["kind"])[e["index"]]) for e in entries]
    kept = [None if f is None else load_samples(f, table_size(e))
            for f, e in zip(files, entries)]
    if all(k is not None for k in kept):
        for e, samples in zip(entries, kept):
            out[e["offset"]:e["offset"] + table_size(e)] = samples
        return out
    module = _lowered(source, filename, tuple(str(p) for p in search_paths or ()))
    for e, file in zip(entries, files):
        inst = getattr(scene, e["kind"])[e["index"]]
        params = table_params(module.functions[e["fn"] + ".read"], inst)
        # the same plugin source, table and values give the same samples (a test harness
        # loads one plugin with the same values many times)
        key = (id(module), e["fn"], table_size(e), repr(sorted(params.items())))
        with _lock:
            samples = _samples.get(key)
        if samples is None:
            samples = tabulate(module, e, params)
            with _lock:
                _samples[key] = samples
        if file is not None:
            store_samples(file, samples)
        out[e["offset"]:e["offset"] + table_size(e)] = samples
    return out


def _samples_file(mod: Any, entry: dict[str, Any], inst: Any) -> Path | None:
    """Where the samples of table ``entry`` of ``mod`` (generic kernels loaded from the
    kernel cache) for instance ``inst`` are kept: ``<cache>/tables/fill-<sha256>.npy`` of
    the kernels' entry name, the table and the instance's plain values (a colour or a
    texture cannot reach a table: compiler/precompute.py); None for kernels outside the
    cache."""
    import hashlib

    from ..core.cachedir import cache_dir

    path = getattr(mod, "path", None)
    if path is None or Path(path).parent.parent != cache_dir():
        return None
    plain = (bool, int, float, np.bool_, np.integer, np.floating)
    values = sorted((k, repr(v)) for k, v in inst.params.items() if isinstance(v, plain))
    what = repr((Path(path).parent.name, entry["fn"], entry.get("n"), entry.get("lo"),
                 entry.get("hi"), entry.get("sum"), values))
    return cache_dir() / "tables" / f"fill-{hashlib.sha256(what.encode()).hexdigest()}.npy"


def _lowered(source: str | Path, filename: str | None, search_paths: tuple[str, ...]) -> Any:
    """The IR of ``source`` straight from the frontend (kept per source in this process; the
    one the compile of its generic kernels lowered, if that ran in this process)."""
    from ..compiler.driver import lowered

    text = source.read_text() if isinstance(source, Path) else str(source)
    key = (text, filename, search_paths)
    with _lock:
        if key not in _ir:
            _ir[key] = lowered(source, filename, [Path(p) for p in search_paths])
        return _ir[key]
