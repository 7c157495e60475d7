"""The files a scene load reads, and the parsed files a reload may take from the load before.

``rdsl render --watch`` re-renders when a file the scene was made of changes, so the loader
notes each file it opens (the XML and its includes, meshes, bitmaps, spectra) and each place
it looked for one that was not there (creating it would change what the scene resolves to).
A load runs inside :func:`recording`; outside one, :func:`note` does nothing and
:func:`memoized` just loads.

Parsing a mesh or an image is the slow part of a reload, so :func:`memoized` hands back the
previous load's result for a file whose size, modification time and inode are unchanged.
Only what the latest load used is kept: memory stays one scene's worth.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

# a file's identity for "unchanged": (size, mtime in ns, inode); None when it is missing
Stamp = tuple[int, int, int] | None


def stamp(path: Path) -> Stamp:
    """``path``'s size, modification time and inode, or None if it does not exist."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns, st.st_ino)


@dataclass
class Reads:
    """What one load read: ``files`` (resolved, in the order first read, missing ones
    included) and the parsed results it may pass on to the next load."""

    files: dict[Path, None] = field(default_factory=dict)  # an ordered set
    parsed: dict[tuple[Path, Hashable], tuple[Stamp, Any]] = field(default_factory=dict)
    previous: dict[tuple[Path, Hashable], tuple[Stamp, Any]] = field(default_factory=dict)

    def note(self, path: str | os.PathLike) -> None:
        self.files.setdefault(Path(path).resolve(), None)


# the recordings in progress, innermost last: a file read is noted in each (a caller can
# record around a load that records its own), a parse is lent by the innermost
_ACTIVE: ContextVar[tuple[Reads, ...]] = ContextVar("rdsl_scene_reads", default=())


def note(path: str | os.PathLike) -> None:
    """Record that the loads in progress read (or looked for) ``path``."""
    for reads in _ACTIVE.get():
        reads.note(path)


def memoized(path: str | os.PathLike, key: Hashable, load: Callable[[], T]) -> T:
    """``load()``, the parse of file ``path`` (``key`` names how it was parsed), or what
    the previous load's identical parse returned when the file has not changed since.
    The result is shared between loads, so callers must not modify it."""
    active = _ACTIVE.get()
    if not active:
        return load()
    note(path)
    reads = active[-1]
    k = (Path(path).resolve(), key)
    now = stamp(k[0])
    old = reads.previous.get(k) or reads.parsed.get(k)
    if old is not None and now is not None and old[0] == now:
        reads.parsed[k] = old
        return old[1]
    value = load()
    reads.parsed[k] = (now, value)
    return value


def first_file(candidates: list[Path]) -> Path | None:
    """The first of ``candidates`` that is a file, noting each one looked at: a file
    created at an earlier place later would be found instead."""
    for c in candidates:
        note(c)
        if c.is_file():
            return c
    return None


@contextmanager
def recording(previous: Reads | None = None) -> Iterator[Reads]:
    """Record the files read inside the ``with`` block (recordings nest: an outer one sees
    the inner one's files too); ``previous`` (the last load's record) lends its parsed
    files.  The record is complete even if the load fails."""
    reads = Reads(previous=dict(previous.parsed) if previous is not None else {})
    token = _ACTIVE.set((*_ACTIVE.get(), reads))
    try:
        yield reads
    finally:
        _ACTIVE.reset(token)
        reads.previous = {}
