"""A kernel call's results: the arrays the kernel wrote, as the caller sees them ((N,) and
(N, k) arrays, dicts for structs, tuples), and the leaf arrays of an ``out=`` shaped like
one."""

from __future__ import annotations

from typing import Any

import numpy as np


def build_result(t: dict[str, Any], arrays: Any, n: int) -> Any:
    """The result of type ``t`` from the output ``arrays`` (an iterator, in leaf order).
    A plain function, not a recursive closure: a closure's cycle would keep the arrays
    alive until the garbage collector runs, and the output pool could not reuse them."""
    kind = t["kind"]
    if kind == "scalar":
        arr = next(arrays)
        return arr.view(np.bool_) if t["dtype"] == "bool" else arr
    if kind in ("vec", "mat"):
        k = t["n"] if kind == "vec" else t["n"] * t["n"]
        out = _columns([next(arrays) for _ in range(k)], n)
        return out.reshape(n, t["n"], t["n"]) if kind == "mat" else out
    if kind == "struct":
        return {f: build_result(ft, arrays, n) for f, ft in t["fields"]}
    if kind == "tuple":
        return tuple(build_result(e, arrays, n) for e in t["elems"])
    raise TypeError(t)


def walk_out(v: Any, t: dict[str, Any], n: int, leaves: list[np.ndarray]) -> bool:
    """Append the leaf arrays of ``v``, an ``out=`` of type ``t`` over ``n`` elements, to
    ``leaves`` (views, any strides); False where it is not shaped like one."""
    kind = t["kind"]
    if kind == "struct":
        return isinstance(v, dict) and all(f in v and walk_out(v[f], ft, n, leaves)
                                           for f, ft in t["fields"])
    if kind == "tuple":
        return isinstance(v, tuple) and len(v) == len(t["elems"]) and \
            all(walk_out(e, et, n, leaves) for e, et in zip(v, t["elems"]))
    if not isinstance(v, np.ndarray):
        return False
    k = t.get("n", 0)
    if kind == "vec" and v.shape == (n, k):
        leaves.extend(v[:, j] for j in range(k))
    elif kind == "mat" and v.shape == (n, k, k):
        leaves.extend(v[:, r, c] for r in range(k) for c in range(k))
    elif kind == "scalar" and v.shape == (n,):
        leaves.append(v)
    else:
        return False
    return True


def _columns(cols: list[np.ndarray], n: int) -> np.ndarray:
    """``cols`` as the columns of an (n, k) array: a transposed view when they are
    consecutive rows of one block (as the kernel call allocates them), else a copy."""
    first = cols[0]
    step = first.itemsize * n
    base = first.base
    if n > 0 and base is not None and all(c.base is base and
                                c.ctypes.data == first.ctypes.data + j * step
                                for j, c in enumerate(cols)):
        row0 = (first.ctypes.data - base.ctypes.data) // step
        return base[row0:row0 + len(cols)].T
    return np.stack(cols, axis=1)
