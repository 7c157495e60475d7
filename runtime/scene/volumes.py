"""The volumes a ``volume`` texture reads (Mitsuba 3's ``gridvolume`` and ``constvolume``):
their samples as a grid (z, y, x, channels) over the unit cube of the volume's frame, and
that frame.  rdsl has no participating media, so a volume is only ever a texture's.

A ``gridvolume`` reads a ``.vol`` file (runtime/scene/volgrid.py) of 1 or 3 channels; with
``use_grid_bbox`` its frame is the file's bounding box, placed by ``to_world``.  A
``constvolume`` is one sample (its ``value``) that clamping spreads over all of space.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from . import transform as xf
from .reads import memoized
from .volgrid import VolError, read_vol


def _load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
        grid, bbox = read_vol(path)
    except VolError as e:
        raise ValueError(f"not a Mitsuba volume grid (.vol) file: {e}") from None
    if grid.shape[3] not in (1, 3):
        raise ValueError(f"the grid has {grid.shape[3]} channels; a volume texture reads 1 "
                         "or 3")
    if not np.isfinite(grid).all():
        raise ValueError("the grid holds values that are not finite")
    return grid, bbox


def load_volume_grid(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The samples (z, y, x, 1 or 3 channels) and bounding box of the ``.vol`` file
    ``path``, checked (ValueError: what is wrong; OSError: an unreadable file)."""
    p = Path(path)
    return memoized(p, ("volume texture",), lambda: _load(p))


def volume_grid(volume: Any) -> tuple[np.ndarray, np.ndarray]:
    """(samples (z, y, x, 3), to_world 4x4) of a loaded volume plugin: a one-channel
    grid's samples repeated in three channels; the frame with the grid's bounding box."""
    p = volume.params
    to_world = np.asarray(p["to_world"], np.float64)
    if volume.type == "constvolume":
        rgb = np.asarray(p["value"].rgb, np.float32)
        return rgb.reshape(1, 1, 1, 3), to_world
    grid, bbox = load_volume_grid(p["filename"])
    if p["use_grid_bbox"]:
        lo, hi = np.asarray(bbox, np.float64)
        to_world = to_world @ xf.translate(lo) @ xf.scale(hi - lo)
    if grid.shape[3] == 1:
        grid = np.repeat(grid, 3, axis=3)
    return grid, to_world
