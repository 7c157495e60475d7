"""The render kernel's sensor: which struct of stdlib/render/camera.rdsl or sensors.rdsl
generates its rays, with the per-scene values of its fields.

``perspective`` and ``thinlens`` are the `Camera` (runtime/render/camera.py); the others
are declared in stdlib/render/sensors.rdsl, which the kernel then imports.  An
``irradiancemeter`` weights the radiance of its cosine-distributed rays by pi, so that the
pixel's mean is the irradiance (Mitsuba's sample_ray returns that weight).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .camera import camera_uniforms

__all__ = ["sensor_struct"]

# the sensors of stdlib/render/sensors.rdsl -> (struct, weight of the radiance or None)
_STRUCTS = {"orthographic": ("OrthoCamera", None), "radiancemeter": ("RadianceMeter", None),
            "irradiancemeter": ("IrradianceMeter", "pi()")}
_METER_KINDS = {"rectangle": 0, "disk": 1, "sphere": 2}


def _vec(v: Any) -> list[float]:
    return [float(x) for x in np.asarray(v, np.float64)[:3]]


def sensor_struct(sensor: Any) -> tuple[str, dict[str, Any], str | None, str | None]:
    """(struct name, field values, module to import or None, rdsl weight of L or None)."""
    if sensor.type not in _STRUCTS:
        return "Camera", camera_uniforms(sensor), None, None
    name, weight = _STRUCTS[sensor.type]
    p = sensor.params
    m = np.asarray(p["to_world"], np.float64)
    if sensor.type == "irradiancemeter":
        m = np.asarray(sensor.shape.params["to_world"], np.float64)
    basis = [m[:3, j] / np.linalg.norm(m[:3, j]) for j in range(3)]
    if sensor.type == "radiancemeter":
        fields = {"origin": _vec(p["origin"]), "dir": _vec(p["direction"])}
    elif sensor.type == "irradiancemeter":
        fields = _meter_fields(sensor.shape)
    else:
        fields = _ortho_fields(sensor)
    fields = {"basis": dict(zip("stn", map(_vec, basis), strict=True)), **fields}
    return name, fields, "render.sensors", weight


def _ortho_fields(sensor: Any) -> dict[str, Any]:
    """Mitsuba's orthographic_projection: film x in [0, 1] -> camera x 1 .. -1, y -> 1/aspect
    .. -1/aspect, on the near plane; the crop window as for the perspective camera."""
    p, film = sensor.params, sensor.film
    m = np.asarray(p["to_world"], np.float64)
    width, height = int(film["width"]), int(film["height"])
    cx, cy = int(film["crop_offset_x"]), int(film["crop_offset_y"])
    cw, ch = int(film["crop_width"]), int(film["crop_height"])
    az = m[:3, 2]
    return {
        "origin": _vec(m[:3, 3]), "ax": _vec(m[:3, 0]), "ay": _vec(m[:3, 1]), "az": _vec(az),
        "dir": _vec(az / np.linalg.norm(az)),
        "half": [1.0, height / width],
        "crop_offset": [cx / width, cy / height],
        "crop_scale": [cw / width, ch / height],
        "crop_offset_px": [float(cx), float(cy)],
        "inv_crop_size": [1.0 / cw, 1.0 / ch],
        "near_clip": float(p["near_clip"]),
        "far_clip": float(p["far_clip"]),
    }


def _meter_fields(shape: Any) -> dict[str, Any]:
    """The measured shape's placement: a rectangle's and a disk's axes (their to_world),
    a sphere's center and radius, the normal with ``flip_normals`` applied."""
    m = np.asarray(shape.params["to_world"], np.float64)
    lin = m[:3, :3]
    n = np.linalg.inv(lin).T @ np.array([0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    flip = bool(shape.params["flip_normals"])
    radius = float(np.linalg.norm(lin[:, 0])) if shape.type == "sphere" else 0.0
    if shape.analytic is not None:
        flip = shape.analytic.flipped
    return {"kind": _METER_KINDS[shape.type], "center": _vec(m[:3, 3]), "ax": _vec(lin[:, 0]),
            "ay": _vec(lin[:, 1]), "n": _vec(-n if flip else n), "radius": radius,
            "flip": -1.0 if flip else 1.0}
