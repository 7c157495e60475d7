"""Output blocks that a kernel reuses from call to call, once nobody holds them any more.

A call without ``out=`` returns fresh arrays.  For large outputs, fresh memory is expensive:
every page is faulted in and zeroed by the OS on first write.  Measured on
``bench/ggx_kernel.rdsl`` (4M samples, a 64 MB output, one AVX-512 thread, on a loaded
2-core machine): the kernel's own work is about 44 ms of CPU time, a fresh output adds
15 to 200 ms more (page faults, and transparent huge page compaction when memory is
fragmented); in later runs of ``bench/vector_speedup.py`` (about 50 ms of work) +9 to +13 ms
(544 page faults: huge pages).  So each kernel keeps a few blocks: a block is handed out again only when the
pool holds the only reference to it (no result, view or buffer export of it is alive), so a
caller can never see its arrays change under it.  The pattern ``out = k(x)`` in a loop then
alternates between two blocks and faults in no fresh pages after the second call.
"""

from __future__ import annotations

import sys
import threading
from typing import Any

import numpy as np

MIN_BYTES = 1 << 20  # smaller blocks come cheaply from the allocator's free lists
BLOCKS_PER_DTYPE = 2  # `out = k(x)` in a loop: the previous result is alive during the call


def _refs(blocks: list[np.ndarray], j: int) -> int:
    return sys.getrefcount(blocks[j])


def _fits(blocks: list[np.ndarray], j: int, shape: tuple[int, ...], dtype: np.dtype) -> bool:
    return blocks[j].shape == shape and blocks[j].dtype == dtype


_ALONE = _refs([np.empty(0)], 0)  # the count of a block only the pool's list refers to


class OutputPool:
    """The blocks one kernel's calls write their fresh outputs into (``capacity`` blocks of
    each dtype at most; 0 turns reuse off)."""

    def __init__(self, capacity: int = BLOCKS_PER_DTYPE) -> None:
        self.capacity = capacity
        self._blocks: list[np.ndarray] = []
        self._lock = threading.Lock()  # two threads calling one kernel take distinct blocks

    def block(self, shape: tuple[int, ...], dtype: Any, zero: bool) -> np.ndarray:
        """An array of ``shape`` and ``dtype`` (zero-filled when ``zero``) that no one else
        refers to: a pooled one when free, else a new one (pooled when large)."""
        dtype = np.dtype(dtype)
        if self.capacity <= 0 or int(np.prod(shape)) * dtype.itemsize < MIN_BYTES:
            return np.zeros(shape, dtype) if zero else np.empty(shape, dtype)
        with self._lock:
            found = self._take(shape, dtype)
            if found is None:
                found = np.empty(shape, dtype)
                self._add(found)
        if zero:
            found.fill(0)
        return found

    def clear(self) -> None:
        """Drop every pooled block (their memory is freed once no result refers to it)."""
        with self._lock:
            self._blocks.clear()

    def _take(self, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray | None:
        # by index, without a loop variable: any local name would count as a reference
        for j in range(len(self._blocks)):
            if _fits(self._blocks, j, shape, dtype) and _refs(self._blocks, j) == _ALONE:
                return self._blocks[j]
        return None

    def _add(self, new: np.ndarray) -> None:
        same = [j for j in range(len(self._blocks)) if self._blocks[j].dtype == new.dtype]
        if len(same) >= self.capacity:
            # drop a block nobody uses (the oldest first), else the oldest: a block still
            # in use stays valid for its holder, the pool just forgets it
            free = [j for j in same if _refs(self._blocks, j) == _ALONE]
            del self._blocks[(free or same)[0]]
        self._blocks.append(new)
