"""Per-scene setup of the `Camera` struct of ``stdlib/render/camera.rdsl``.

This is the once-per-render part of Mitsuba 3's ``perspective``/``thinlens`` constructors
(``perspective_projection`` in sensor.h); the per-sample ray generation is in the stdlib.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["camera_uniforms"]


def camera_uniforms(sensor: Any) -> dict[str, Any]:
    """The `Camera` field values for a loaded sensor (``rdsl.runtime.scene.Sensor``).

    Returns a dict of Python floats / float lists, shaped as the kernel API wants a struct:
    ``{"origin": [x, y, z], "basis": {"s": ..., "t": ..., "n": ...}, ...}``.
    """
    p = sensor.params
    film = sensor.film
    if film is None:
        raise ValueError("the sensor has no film")
    m = np.asarray(p["to_world"], dtype=np.float64)
    width, height = int(film["width"]), int(film["height"])
    cx, cy = int(film["crop_offset_x"]), int(film["crop_offset_y"])
    cw, ch = int(film["crop_width"]), int(film["crop_height"])
    aspect = width / height
    tan_x = math.tan(math.radians(float(p["fov_x"])) / 2)
    aperture = float(p.get("aperture_radius", 0.0) or 0.0) if sensor.type == "thinlens" else 0.0
    if sensor.type == "thinlens" and aperture == 0.0:
        aperture = 2.0 ** -24  # Mitsuba replaces a zero aperture by machine epsilon
    ppo = (float(p.get("principal_point_offset_x", 0.0) or 0.0),
           float(p.get("principal_point_offset_y", 0.0) or 0.0))

    def col(j: int) -> list[float]:
        return [float(v) for v in m[:3, j]]

    return {
        "origin": col(3),
        "basis": {"s": col(0), "t": col(1), "n": col(2)},
        "tan_half": [tan_x, tan_x / aspect],
        # Mitsuba's principal point offset is in units of the whole film: it shifts the
        # film-relative position (film size * ppo / crop size, scaled back by crop / film)
        "crop_offset": [cx / width + ppo[0], cy / height + ppo[1]],
        "crop_scale": [cw / width, ch / height],
        "crop_offset_px": [float(cx), float(cy)],
        "inv_crop_size": [1.0 / cw, 1.0 / ch],
        "near_clip": float(p["near_clip"]),
        "far_clip": float(p["far_clip"]),
        "aperture_radius": aperture,
        "focus_distance": float(p["focus_distance"]),
    }
