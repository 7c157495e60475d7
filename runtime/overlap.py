"""Which of a kernel call's arrays share memory with its ``out=`` arrays.

A kernel reads lane i's inputs before it writes lane i's outputs, but it writes lanes
``[0, k)`` before it reads lane k (chunks of the SIMD width, then threads' ranges).  So an
``out=`` array may be an input itself (``k(x, out=x)``: lane i is read, then written), or
the other components of the same rows (``out=p[:, ::-1]`` for a ``Vec3`` param ``p``), but
not memory that another lane reads (``out=x[::-1]``, ``out=x[1:]`` with ``x[:-1]``): that
lane would read a result instead of its input.  Such an input is copied before the call, as
numpy's ufuncs do.  Two outputs in the same memory are the caller's mistake: one result
would be lost.

An array here is a *span*: the address of its lane 0, its byte stride and its item size.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Span(NamedTuple):
    """One 1-D array argument of a call: lane i is bytes ``[addr + i * stride, + size)``."""

    addr: int
    stride: int
    size: int


def _bounds(a: Span, n: int) -> tuple[int, int]:
    addr, stride, size = a
    last = addr + stride * (n - 1)
    return (addr, last + size) if stride >= 0 else (last, addr + size)


def _lanes_meet(a: Span, b: Span, n: int, other_lanes_only: bool) -> bool:
    """Whether a byte of lane i of ``a`` is a byte of lane j of ``b`` for some lanes i, j
    below ``n`` (with i != j only, when ``other_lanes_only``), given that their byte ranges
    meet.  Exact for equal strides, otherwise True."""
    a_addr, s, a_size = a
    b_addr, b_stride, b_size = b
    if b_stride != s or abs(s) < max(a_size, b_size):
        return True
    # lane i + k of b starts d + k * s bytes after lane i of a; they share a byte when
    # that offset is in (-b_size, a_size), which only the k nearest -d / s can give
    d = b_addr - a_addr
    k0 = -d // s
    for k in (k0 - 1, k0, k0 + 1, k0 + 2):
        if -b_size < d + k * s < a_size and abs(k) < n and (k or not other_lanes_only):
            return True
    return False


def overwritten_inputs(inputs: list[Span], outputs: list[Span], n: int) -> list[int]:
    """The indices of ``inputs`` that some lane would read after another lane wrote one of
    ``outputs`` over them (to be copied before the call)."""
    if not outputs or n <= 1:  # one lane reads all its inputs before it writes
        return []
    out_bounds = [_bounds(o, n) for o in outputs]
    lo, hi = min(b[0] for b in out_bounds), max(b[1] for b in out_bounds)
    found = []
    for i, a in enumerate(inputs):
        a_lo, a_hi = _bounds(a, n)
        if a_hi <= lo or hi <= a_lo:  # the common case: nowhere near the outputs
            continue
        if any(a_lo < o_hi and o_lo < a_hi and _lanes_meet(o, a, n, True)
               for o, (o_lo, o_hi) in zip(outputs, out_bounds)):
            found.append(i)
    return found


def shared_outputs(outputs: list[Span], arrays: list[np.ndarray], n: int
                   ) -> tuple[int, int] | None:
    """Two of ``outputs`` (the spans of ``arrays``) that share a byte, or None."""
    if n <= 0:
        return None
    bounds = [_bounds(o, n) for o in outputs]
    for i in range(len(outputs)):
        lo, hi = bounds[i]
        for j in range(i + 1, len(outputs)):
            if hi <= bounds[j][0] or bounds[j][1] <= lo:
                continue
            a, b = outputs[i], outputs[j]
            if not _lanes_meet(a, b, n, False):
                continue
            exact = a[1] == b[1] and abs(a[1]) >= max(a[2], b[2])
            if exact or np.shares_memory(arrays[i], arrays[j]):
                return i, j
    return None
