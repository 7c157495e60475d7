"""The Embree 4 C ABI as rdsl uses it: struct layouts, constants, and where libembree4 is.

Both sides of rdsl meet Embree: the LLVM backend emits calls to ``rtcIntersectN`` /
``rtcOccludedN`` and the user-geometry callbacks (``compiler/backends/embree_llvm.py``,
``compiler/backends/llvm_shapes.py``), the runtime loads the library and builds scenes
through ctypes (``runtime/embree.py``, ``runtime/embree_user.py``).  The facts they must
agree on live here, as plain data: no llvmlite, no ctypes.

Layout (Embree 4.4 release builds: ``RTC_MAX_INSTANCE_LEVEL_COUNT`` = 1 and
``RTC_GEOMETRY_INSTANCE_ARRAY`` on). A width-N packet (N = 4, 8, 16) is structure of arrays,
aligned to 4N bytes; every field is an ``[N x float|uint]`` row:

    ray: org_x org_y org_z tnear dir_x dir_y dir_z time tfar mask id flags   (12 rows)
    hit: Ng_x Ng_y Ng_z u v primID geomID instID[1] instPrimID[1]            (9 rows)

The single ray (N = 1) has the same fields as scalars; ``RTCRay`` and ``RTCHit`` are each
aligned (and padded) to 16 bytes, so ``RTCRayHit`` is 48 + 48 bytes. A build without
instance arrays never writes the ``instPrimID`` row, so this layout is safe for it as well.

The analytic shapes (spheres, disks) are Embree user geometries whose callbacks the backend
generates and the runtime registers; each reads a block of :data:`USER_BLOCK_DOUBLES`
doubles (its ``geometryUserPtr``), laid out as :data:`USER_BLOCK` says, in world space.
"""

from __future__ import annotations

import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path

RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF
WIDTHS = (1, 4, 8, 16)
QUERIES = ("Intersect", "Occluded")
QUERY_FUNCTIONS = tuple(f"rtc{q}{w}" for q in QUERIES for w in WIDTHS)

RAY_FIELDS = ("org_x", "org_y", "org_z", "tnear", "dir_x", "dir_y", "dir_z", "time",
              "tfar", "mask", "id", "flags")
HIT_FIELDS = ("Ng_x", "Ng_y", "Ng_z", "u", "v", "primID", "geomID", "instID", "instPrimID")
UINT_FIELDS = frozenset({"mask", "id", "flags", "primID", "geomID", "instID", "instPrimID"})
# one entry per instance level (RTC_MAX_INSTANCE_LEVEL_COUNT = 1): [1 x ...] arrays
INSTANCE_FIELDS = ("instID", "instPrimID")

# rdsl's user geometries: their kinds, the callbacks generated for them (``rdsl_user_<name>``)
# and the block of doubles each reads, as (first index, length) in world space
USER_KINDS = ("sphere", "disk", "sdfgrid")
# ... and the filter that culls the back faces of curves, as Mitsuba's Embree build does
USER_CALLBACKS = ("bounds", *(f"{k}_{q}" for k in USER_KINDS for q in ("intersect", "occluded")),
                  "backface_filter")
USER_BLOCK_DOUBLES = 24
USER_BLOCK = {
    "center": (0, 3), "radius": (3, 1),           # sphere
    "to_object": (0, 12), "normal": (12, 3),      # disk: rows of a 3 x 4 matrix, unit normal
    # sdfgrid: the address of its rdsl kernel (stdlib/render/sdfgrid_kernel.rdsl) and of
    # its record, as int64 bit patterns
    "kernel": (0, 1), "record": (1, 1),
    "lower": (16, 3), "upper": (19, 3),           # all: the bounding box
}


class EmbreeError(RuntimeError):
    """Embree is missing, or an Embree call reported an error."""


def check_width(width: int) -> int:
    """``width`` if Embree has packets of it (1, 4, 8, 16), else a ValueError."""
    if width not in WIDTHS:
        raise ValueError(f"width: Embree packets are 1, 4, 8 or 16 wide, got {width!r}")
    return width


@dataclass(frozen=True)
class PacketLayout:
    """Where each field of an ``RTCRayHitN`` (or ``RTCRayN``) lies, in 4-byte words."""

    width: int
    with_hit: bool = True

    @property
    def align(self) -> int:
        """Required alignment in bytes: 16, 16, 32, 64 for widths 1, 4, 8, 16."""
        return max(16, 4 * self.width)

    @property
    def ray_words(self) -> int:
        return 12 * self.width

    @property
    def words(self) -> int:
        """Size of the whole struct in words (a multiple of the alignment)."""
        if not self.with_hit:
            return self.ray_words
        hit = len(HIT_FIELDS) * self.width
        hit = -(-hit // (self.align // 4)) * (self.align // 4)  # RTCHit pads to 16 bytes
        return self.ray_words + hit

    @property
    def nbytes(self) -> int:
        return 4 * self.words

    def offset(self, field: str) -> int:
        """Word offset of lane 0 of ``field``; lane i is at ``offset + i``."""
        if field in RAY_FIELDS:
            return RAY_FIELDS.index(field) * self.width
        if self.with_hit and field in HIT_FIELDS:
            return self.ray_words + HIT_FIELDS.index(field) * self.width
        raise KeyError(f"no field {field!r} in {'RTCRayHit' if self.with_hit else 'RTCRay'}"
                       f"{self.width if self.width > 1 else ''}")


def embree_library_path() -> Path:
    """The ``libembree4`` shared library shipped in the ``embreex`` wheel.

    ``$RDSL_EMBREE_LIBRARY`` overrides the search (a path to a libembree4 of version 4)."""
    override = os.environ.get("RDSL_EMBREE_LIBRARY")
    if override:
        p = Path(override)
        if not p.is_file():
            raise EmbreeError(f"$RDSL_EMBREE_LIBRARY names {p}, which is not a file")
        return p
    try:
        dist = importlib.metadata.distribution("embreex")
    except importlib.metadata.PackageNotFoundError:
        raise EmbreeError("Embree 4 is not available: the `embreex` package is not installed "
                          "(pip install 'embreex>=4.3,<5'); it ships libembree4") from None
    found = []
    for f in dist.files or ():
        name = f.name
        if name.startswith("libembree4") and (".so" in name or name.endswith(".dylib")):
            found.append(Path(dist.locate_file(f)))
    found = sorted(p for p in found if p.is_file())
    if not found:
        raise EmbreeError(f"the installed `embreex` {dist.version} has no libembree4 shared "
                          "library among its files; reinstall it from a binary wheel")
    return found[0]


def link_args() -> list[str]:
    """``cc`` arguments that link a shared library against the wheel's libembree4.

    The wheel's library has a hashed file name (``libembree4-<hash>.so.4``), so it is named
    with ``-l:`` and found at run time through an rpath."""
    path = embree_library_path()
    return [f"-L{path.parent}", f"-l:{path.name}", f"-Wl,-rpath,{path.parent}"]


__all__ = [
    "HIT_FIELDS", "INSTANCE_FIELDS", "QUERIES", "QUERY_FUNCTIONS", "RAY_FIELDS",
    "RTC_INVALID_GEOMETRY_ID", "UINT_FIELDS", "USER_BLOCK", "USER_BLOCK_DOUBLES",
    "USER_CALLBACKS", "USER_KINDS", "WIDTHS", "EmbreeError", "PacketLayout", "check_width",
    "embree_library_path", "link_args",
]
