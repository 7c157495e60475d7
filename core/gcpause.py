"""Python's cycle collector paused for the length of a compile."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def gc_paused() -> Iterator[None]:
    """Python's cycle collector off for a compile.  The IR is cyclic (values point at their
    instructions and back) and a compile allocates hundreds of thousands of objects, so the
    collector ran again and again over a growing heap: 40% of the passes' time on a
    material-preview scene (bench/scene_set.py).  The garbage is collected once, afterwards."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()
