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
    need = MIN_POINTS[kind]
    points: list[tuple[float, float, float, float]] = []
    segments: list[int] = []
    first, first_line = 0, 0  # the current curve's first point and its line

    def finish(end_line: int) -> None:
        count = len(points) - first
        if count == 0:
            return
        if count < need:
            raise CurveError(f"the curve starting at line {first_line} has {count} control "
                             f"point{'s' if count != 1 else ''}; a {kind} needs at least "
                             f"{need}", end_line)
        segments.extend(range(first, len(points) - need + 1))

    with open(path, encoding="utf-8", errors="replace") as f:
        lines = f.read().splitlines()
    for n, text in enumerate(lines, start=1):
        if not text.strip():
            finish(n - 1)
            first, first_line = len(points), 0
            continue
        if first_line == 0:
            first_line = n
        points.append(_parse_line(text, n))
    finish(len(lines))
    if not points:
        raise CurveError("the file holds no control points")
    return Curves(kind, np.asarray(points, np.float32), np.asarray(segments, np.uint32))


__all__ = ["CURVE_TYPES", "CurveError", "Curves", "read_curves"]
