"""The on-disk kernel cache: ``$RDSL_CACHE_DIR`` (default ``~/.cache/rdsl``)/``<key>/``.

The key hashes everything the compiled code depends on: the source text, the text of every
file it imports (stdlib included), the target, variant and width, compiler options, the rdsl
version and a fingerprint of the compiler's own code."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.cachedir import cache_dir, compiler_fingerprint

__all__ = ["STEM", "cache_dir", "cache_key", "compiler_fingerprint", "entry_complete"]

if TYPE_CHECKING:
    from ..compiler.build import Build

STEM = "kernels"  # file names inside a cache entry: kernels.so, kernels.h, kernels.json


def cache_key(source_text: str, files: Iterable[os.PathLike | str], build: Build,
              options: dict[str, Any]) -> str:
    """The sha256 key of one compilation for ``build``."""
    from .. import __version__

    h = hashlib.sha256()

    def part(tag: str, data: bytes | str) -> None:
        b = data.encode() if isinstance(data, str) else data
        h.update(f"{tag}:{len(b)}:".encode())
        h.update(b)

    part("version", __version__)
    part("compiler", compiler_fingerprint())
    part("target", build.target.name)
    part("variant", build.model.name)
    part("width", str(build.width))
    if build.ad is not None:  # keys of builds without AD stay as they were
        part("ad", build.ad)
    if getattr(build, "eliminate", 0):
        part("eliminate", str(build.eliminate))
    if getattr(build, "tape", 0):
        part("tape", str(build.tape))
    if getattr(build, "tape_covers", False):
        part("tape_covers", "1")
    if getattr(build, "seeds", None) is not None:
        part("seeds", json.dumps(list(build.seeds)))
    part("options", json.dumps(options, sort_keys=True, default=repr))
    part("source", source_text)
    for f in files:
        p = Path(f)
        part("file", str(p))
        try:
            part("text", p.read_bytes())
        except OSError:
            part("text", "<missing>")
    return h.hexdigest()


def entry_complete(d: Path) -> bool:
    # a native library, the OpenCL C program of target opencl, or target spirv's SPIR-V
    return (d / f"{STEM}.json").is_file() and \
        any((d / f"{STEM}{s}").is_file() for s in (".so", ".cl", ".spv"))
