"""Filling the generic build's tables at scene load.

A plugin's ``table`` functions (docs/language.md, "Tables") are computed once per scene.  The
specialized build folds them into its code at compile time; the generic build, whose code
does not depend on parameter values, reserves room for them at the end of ``PRM`` and lists
them in its manifest (``tables``: the table function, its sampling, the instance, the offset).
:func:`fill_tables` computes them for the scene's values with the same compiled table
kernels (:func:`rdsl.compiler.precompute.tabulate`) and returns the complete ``PRM``.
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
    from ..compiler.precompute import table_params, table_size, tabulate

    module = _lowered(source, filename, tuple(str(p) for p in search_paths or ()))
    size = max(int(e["offset"]) + table_size(e) for e in entries)
    out = np.zeros(max(size, len(prm), 1), np.float32)
    out[:len(prm)] = prm
    for e in entries:
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
        out[e["offset"]:e["offset"] + table_size(e)] = samples
    return out


def _lowered(source: str | Path, filename: str | None, search_paths: tuple[str, ...]) -> Any:
    """The IR of ``source`` straight from the frontend (kept per source in this process)."""
    from ..compiler.driver import frontend

    text = source.read_text() if isinstance(source, Path) else str(source)
    key = (text, filename, search_paths)
    with _lock:
        if key not in _ir:
            _ir[key] = frontend(source, filename, [Path(p) for p in search_paths])
        return _ir[key]
