"""Python's cycle collector paused for the length of a compile."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def gc_paused() -> Iterator[None]:
    """Python's cycle collector off for a compile.  A compile allocates hundreds of
    thousands of objects, so the collector ran again and again over a growing heap: 40% of
    the passes' time on a material-preview scene (bench/scene_set.py).  A compile leaves no
    cycles behind (the frontend, the IR and the LLVM module are freed by reference counting:
    tests/test_compile_garbage.py), so nothing is left for the collector afterwards either."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
