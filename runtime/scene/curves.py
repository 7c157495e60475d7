"""Mitsuba 3's ``linearcurve`` and ``bsplinecurve`` shapes (shapes/linearcurve.cpp,
shapes/bsplinecurve.cpp): round tubes of varying radius along polylines or uniform cubic
B-splines, read from Mitsuba's curve text files.

The file holds one control point per line, ``x y z radius``; a blank line starts a new
curve.  A linear curve needs at least 2 control points and has one segment per pair of
neighbours; a B-spline needs at least 4 and has one segment per 4 consecutive points.  As in
Mitsuba, ``to_world`` moves the points and leaves the radii alone.  rdsl intersects them
with Embree's round curves (runtime/embree_curves.py) and shades them as Mitsuba does
(stdlib/render/geometry.rdsl's ``curve_interaction``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import transform as xf

CURVE_TYPES = ("linearcurve", "bsplinecurve")
# the fewest control points of a curve, and how many points a segment spans
MIN_POINTS = {"linearcurve": 2, "bsplinecurve": 4}


class CurveError(ValueError):
    """A malformed curve file: the message and the (1-based) line, 0 for the whole file."""

    def __init__(self, message: str, line: int = 0) -> None:
        super().__init__(message)
        self.line = line


@dataclass
class Curves:
    """A curve shape in world space: control points (N, 4) float32 (x, y, z, radius) and the
    index of each segment's first control point (uint32)."""

    kind: str
    points: np.ndarray
    segments: np.ndarray

    def with_transform(self, m: np.ndarray) -> Curves:
        """The curves with their points placed by the 4x4 ``m`` (radii unchanged)."""
        pts = self.points.astype(np.float64)
        moved = xf.apply_points(m, pts[:, :3])
        out = np.column_stack([moved, pts[:, 3]]).astype(np.float32)
        return Curves(self.kind, out, self.segments)

    def bounds_points(self) -> np.ndarray:
        """Points whose bounding box is the curves' (each point grown by its radius)."""
        p = self.points.astype(np.float64)
        r = np.abs(p[:, 3:4])
        return np.vstack([p[:, :3] - r, p[:, :3] + r])


def _parse_line(text: str, line: int) -> tuple[float, float, float, float]:
    fields = text.split()
    if len(fields) != 4:
        raise CurveError(f"expected a control point 'x y z radius' (4 numbers), got "
                         f"{len(fields)} field{'s' if len(fields) != 1 else ''}: "
                         f"'{text.strip()}'", line)
    try:
        values = [float(f) for f in fields]
    except ValueError:
        raise CurveError(f"expected a control point 'x y z radius' (4 numbers), got "
                         f"'{text.strip()}'", line) from None
    if not all(np.isfinite(values)):
        raise CurveError(f"the control point '{text.strip()}' is not finite", line)
    if values[3] < 0:
        raise CurveError(f"the control point's radius must not be negative, got "
                         f"{fields[3]}", line)
    return values[0], values[1], values[2], values[3]


def read_curves(kind: str, path: str | Path) -> Curves:
    """Parse a Mitsuba curve file (object space); raises :class:`CurveError` or OSError."""
    with open(path, encoding="utf-8", errors="replace") as f:
        text = f.read()
    lines = text.splitlines()
    counts = np.fromiter((len(line.split()) for line in lines), np.int64, len(lines))
    filled = np.flatnonzero(counts)
    if not len(filled):
        raise CurveError("the file holds no control points")
    try:
        if np.any(counts[filled] != 4):
            raise ValueError
        with warnings.catch_warnings():  # numpy warns where a number does not parse
            warnings.simplefilter("error")
            values = np.fromstring(text, sep=" ")  # C parsing: a million points in a second
        if len(values) != 4 * len(filled):
            raise ValueError
        values = values.reshape(-1, 4)
        if not np.all(np.isfinite(values)) or np.any(values[:, 3] < 0):
            raise ValueError
    except (ValueError, DeprecationWarning):  # find the first bad line, for its message
        for n in filled:
            _parse_line(lines[n], int(n) + 1)
        raise CurveError("the file could not be parsed as numbers") from None
    # a curve is a run of consecutive filled lines
    starts = np.flatnonzero(np.diff(np.r_[-2, filled]) > 1)
    sizes = np.diff(np.r_[starts, len(filled)])
    need = MIN_POINTS[kind]
    short = np.flatnonzero(sizes < need)
    if len(short):
        k = int(short[0])
        first, size = int(filled[starts[k]]) + 1, int(sizes[k])
        raise CurveError(f"the curve starting at line {first} has {size} control "
                         f"point{'s' if size != 1 else ''}; a {kind} needs at least {need}",
                         first + size - 1)
    # each curve's segments start at its points but the last need - 1
    segments = np.concatenate([np.arange(a, a + size - need + 1)
                               for a, size in zip(starts, sizes)])
    return Curves(kind, values.astype(np.float32), segments.astype(np.uint32))


__all__ = ["CURVE_TYPES", "CurveError", "Curves", "read_curves"]
