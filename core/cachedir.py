"""Where rdsl caches what it compiles: ``$RDSL_CACHE_DIR``, default ``~/.cache/rdsl`` (kernel
libraries, runtime/cache.py; parsed sources and the parser's tables, dsl/parser.py; table
samples, compiler/precompute.py; plugin signatures, runtime/plugins.py)."""

from __future__ import annotations

import hashlib
import os
from functools import lru_cache
from collections.abc import Callable
from pathlib import Path
from typing import IO


def cache_dir() -> Path:
    """The root of the cache."""
    env = os.environ.get("RDSL_CACHE_DIR")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "rdsl"


@lru_cache(maxsize=1)
def compiler_fingerprint() -> str:
    """A hash of the compiler's Python sources and grammar, so a changed compiler misses
    (``core`` included: ``lift`` builds its types and tables with it)."""
    root = Path(__file__).resolve().parent.parent  # the package
    h = hashlib.sha256()
    files = [p for sub in ("compiler", "dsl", "core") for p in sorted((root / sub).rglob("*"))
             if p.suffix in (".py", ".lark") and p.is_file()]
    for p in files:
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def write_atomically(path: Path, dump: Callable[[IO[bytes]], object]) -> None:
    """``dump(file)`` into a temporary file in ``path``'s folder, then a rename: another
    process reads a whole entry or none.  Silently nothing in a read-only or full cache
    (what was computed is still right)."""
    import tempfile

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            dump(f)
        os.replace(tmp, path)
    except OSError:
        pass
