"""4x4 float64 affine transforms with Mitsuba 3's conventions.

Inside ``<transform>``, each operation is left-multiplied onto what came before, so
``<scale/><rotate/><translate/>`` scales first and translates last.  ``look_at`` builds a
camera-to-world matrix whose columns are (left, up, forward, origin): the camera looks along
its local +z with +x to the left of the image, as Mitsuba's sensors expect.
"""

from __future__ import annotations

import math

import numpy as np


def identity() -> np.ndarray:
    return np.eye(4)


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, dtype=np.float64)
    return m


def scale(v) -> np.ndarray:
    v = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Right-handed rotation by ``angle_deg`` degrees about ``axis`` (normalized here)."""
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0:
        raise ValueError("rotation axis is zero")
    a = a / n
    th = math.radians(angle_deg)
    s, c = math.sin(th), math.cos(th)
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * cross + (1.0 - c) * np.outer(a, a)
    return m


def look_at(origin, target, up=None) -> np.ndarray:
    """Mitsuba's ``Transform4f::look_at``; ``up`` may be omitted (any perpendicular is used)."""
    o = np.asarray(origin, dtype=np.float64)
    if not (np.isfinite(o).all() and np.isfinite(target).all()
            and (up is None or np.isfinite(up).all())):
        raise ValueError("its points must be finite")
    d = np.asarray(target, dtype=np.float64) - o
    dn = np.linalg.norm(d)
    if dn == 0:
        raise ValueError("'origin' and 'target' coincide")
    d = d / dn
    if up is None:
        up = _any_perpendicular(d)
    left = np.cross(np.asarray(up, dtype=np.float64), d)
    ln = np.linalg.norm(left)
    if ln < 1e-12:
        raise ValueError("'up' is parallel to the viewing direction")
    left = left / ln
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def _any_perpendicular(n: np.ndarray) -> np.ndarray:
    # the first vector of Mitsuba's coordinate_system(n) (Duff et al. 2017), the up vector
    # its parser gives a <lookat> without one (the second one rotated a spot light's
    # projected texture by 90 degrees against Mitsuba's)
    sign = math.copysign(1.0, n[2])
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]])


def from_values(values: list[float]) -> np.ndarray:
    """``<matrix value="...">``: 16 values row-major, or 9 for the linear 3x3 part."""
    if len(values) == 16:
        return np.asarray(values, dtype=np.float64).reshape(4, 4)
    if len(values) == 9:
        m = np.eye(4)
        m[:3, :3] = np.asarray(values, dtype=np.float64).reshape(3, 3)
        return m
    raise ValueError(f"expected 16 (or 9) values, got {len(values)}")


def singular(m: np.ndarray) -> bool:
    """Whether the linear part of ``m`` is singular, or ``m`` holds a NaN or an infinity
    (told apart without numpy's warning on a NaN determinant)."""
    return not np.all(np.isfinite(m)) or abs(np.linalg.det(m[:3, :3])) < 1e-30


def apply_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Transform points (N, 3) by an affine matrix (float64 result)."""
    p = np.asarray(p, dtype=np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def apply_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Transform normals (N, 3) by the inverse transpose, then normalize."""
    inv_t = np.linalg.inv(m[:3, :3]).T
    out = np.asarray(n, dtype=np.float64) @ inv_t.T
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 0, norm, 1.0)


def has_scale(m: np.ndarray, tol: float = 1e-4) -> bool:
    """True when the linear part is not a rotation (cameras reject scaled transforms)."""
    lin = m[:3, :3]
    return not np.allclose(lin.T @ lin, np.eye(3), atol=tol)
