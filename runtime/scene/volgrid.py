"""Mitsuba's binary volume grid files (``.vol``), as its ``VolumeGrid`` reads and writes them.

Layout (little-endian): the bytes ``VOL``, the version byte 3, then int32 ``encoding`` (1:
float32, the only one Mitsuba 3 reads), int32 ``xres``, ``yres``, ``zres``, int32
``channels``, six float32 of the bounding box (min x, y, z, max x, y, z; Mitsuba ignores it
for an sdfgrid, whose grid spans the unit cube) and ``xres * yres * zres * channels`` float32
samples, x fastest: sample ``((z * yres + y) * xres + x) * channels + c``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HEADER = np.dtype([("magic", "S3"), ("version", "u1"), ("encoding", "<i4"), ("res", "<i4", 3),
                   ("channels", "<i4"), ("bbox", "<f4", 6)])


class VolError(ValueError):
    """A file that is not a volume grid Mitsuba could read (the message says why)."""


def read_vol(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The samples of ``path`` as float32 (zres, yres, xres, channels) and its bounding box
    (2, 3).  Raises :class:`VolError` (a malformed file) or OSError (an unreadable one)."""
    data = Path(path).read_bytes()
    if len(data) < HEADER.itemsize:
        raise VolError(f"{len(data)} bytes, shorter than the {HEADER.itemsize}-byte header")
    head = np.frombuffer(data, HEADER, count=1)[0]
    if head["magic"] != b"VOL":
        raise VolError(f"does not start with 'VOL' (found {bytes(head['magic'])!r})")
    if head["version"] != 3:
        raise VolError(f"version {head['version']}, expected 3")
    if head["encoding"] != 1:
        raise VolError(f"encoding {head['encoding']}, expected 1 (float32)")
    res = [int(r) for r in head["res"]]
    channels = int(head["channels"])
    if min(res) < 1 or channels < 1:
        raise VolError(f"resolution {res[0]} x {res[1]} x {res[2]} with {channels} channels")
    count = res[0] * res[1] * res[2] * channels
    size = len(data) - HEADER.itemsize
    if size != 4 * count:
        raise VolError(f"{size} bytes of data, expected {4 * count} ({res[0]} x {res[1]} x "
                       f"{res[2]} x {channels} float32)")
    grid = np.frombuffer(data, "<f4", count=count, offset=HEADER.itemsize)
    return (grid.reshape(res[2], res[1], res[0], channels).astype(np.float32),
            np.asarray(head["bbox"], np.float32).reshape(2, 3))


def write_vol(path: str | Path, grid: np.ndarray, bbox: tuple[float, ...] = (0, 0, 0, 1, 1, 1)
              ) -> None:
    """Write the float32 samples ``grid`` (zres, yres, xres[, channels]) to ``path``."""
    g = np.asarray(grid, np.float32)
    if g.ndim == 3:
        g = g[..., None]
    if g.ndim != 4:
        raise ValueError(f"grid: expected 3 or 4 dimensions (z, y, x[, channels]), got {g.shape}")
    head = np.zeros(1, HEADER)
    head["magic"], head["version"], head["encoding"] = b"VOL", 3, 1
    head["res"] = (g.shape[2], g.shape[1], g.shape[0])
    head["channels"], head["bbox"] = g.shape[3], bbox
    Path(path).write_bytes(head.tobytes() + np.ascontiguousarray(g, "<f4").tobytes())


__all__ = ["VolError", "read_vol", "write_vol"]
