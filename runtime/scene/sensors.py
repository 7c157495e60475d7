"""The loader's checks and derived values of a sensor (Mitsuba 3's sensors/*.cpp).

``perspective`` and ``thinlens`` get their horizontal field of view (``fov_x``);
``orthographic`` may scale in ``to_world`` (its view is [-1, 1]^2 of camera space, scaled);
the measurement sensors ``radiancemeter`` (one ray: ``to_world``, or ``origin`` and
``direction``) and ``irradiancemeter`` (nested in the shape it measures) need a film of one
pixel, as Mitsuba's documentation says, and get one by default.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ...compiler.ir import Loc
from . import transform as xf
from .camera import fov_x
from .errors import scene_error

METERS = ("radiancemeter", "irradiancemeter")
# the shapes an irradiancemeter can measure (sampled uniformly by area in the kernel)
METER_SHAPES = ("rectangle", "disk", "sphere")


def finish_sensor(obj: Any, loc: Callable[[str], Loc]) -> None:
    """Check the sensor ``obj`` (film already attached) and resolve its values;
    ``loc(name)`` is the line of parameter ``name``."""
    p = obj.params
    given = p.get("to_world") is not None
    m = p["to_world"] if given else xf.identity()
    p["to_world"] = m
    if obj.type in METERS:
        film = obj.film
        if (film["width"], film["height"]) != (1, 1):
            raise scene_error(f"{obj.type}: the film must be 1x1 pixels (a measurement "
                              f"sensor), got {film['width']}x{film['height']}", film.loc)
        if obj.type == "radiancemeter":
            _radiancemeter(p, given, loc)
        return
    if obj.type != "orthographic" and xf.has_scale(m):
        raise scene_error(f"sensor '{obj.type}': scale factors in the camera's 'to_world' are "
                          "not allowed", loc("to_world"))
    if abs(np.linalg.det(m[:3, :3])) < 1e-30:
        raise scene_error(f"sensor '{obj.type}': 'to_world' is singular", loc("to_world"))
    for name in ("near_clip", "far_clip", "focus_distance"):
        if p.get(name) is not None and math.isnan(p[name]):
            raise scene_error(f"'{name}' is not a number (nan)", loc(name))
    if p["near_clip"] <= 0:
        raise scene_error("'near_clip' must be greater than zero", loc("near_clip"))
    if p["near_clip"] >= p["far_clip"]:
        raise scene_error("'near_clip' must be smaller than 'far_clip'", loc("near_clip"))
    if obj.type == "orthographic":
        return
    if p["focus_distance"] is None:
        p["focus_distance"] = p["far_clip"]
    aspect = obj.film["width"] / obj.film["height"]
    p["fov_x"] = fov_x(p, aspect, loc)


def _radiancemeter(p: dict[str, Any], to_world: bool, loc: Callable[[str], Loc]) -> None:
    """Mitsuba's radiancemeter: ``origin`` and ``direction``, or ``to_world``, not both."""
    given = [k for k in ("origin", "direction") if p[k] is not None]
    if given and to_world:
        raise scene_error("radiancemeter: give either 'to_world' or 'origin' and 'direction', "
                          "not both", loc(given[0]))
    if given:
        if len(given) != 2:
            missing = ({"origin", "direction"} - set(given)).pop()
            raise scene_error(f"radiancemeter: give both 'origin' and 'direction' (missing "
                              f"'{missing}')", loc(given[0]))
        d = np.asarray(p["direction"], np.float64)
        if not np.any(d):
            raise scene_error("radiancemeter: 'direction' is zero", loc("direction"))
        p["to_world"] = xf.look_at(p["origin"], np.asarray(p["origin"]) + d)
    m = p["to_world"]
    d = m[:3, 2] / np.linalg.norm(m[:3, 2])
    p["origin"], p["direction"] = m[:3, 3].copy(), d


def attach_meter(shape: Any, sensor: Any, child: Any) -> None:
    """Nest the sensor ``sensor`` (the XML ``child``) in ``shape``: only an irradiancemeter,
    on a shape whose surface the kernel samples (a rectangle, a disk or a sphere)."""
    loc = child.loc
    if sensor.type != "irradiancemeter":
        raise scene_error(f"only an 'irradiancemeter' sensor can be nested in a <shape>, not "
                          f"'{sensor.type}'", loc)
    if shape.type not in METER_SHAPES:
        raise scene_error(f"irradiancemeter: rdsl measures the irradiance on a "
                          f"{', '.join(METER_SHAPES[:-1])} or {METER_SHAPES[-1]}, not on a "
                          f"'{shape.type}' shape", loc)
    sensor.shape, shape.sensor = shape, sensor


def top_level_sensor(sensor: Any, loc: Loc) -> Any:
    """A sensor directly inside <scene>: not an irradiancemeter, which measures a shape."""
    if sensor.type == "irradiancemeter":
        raise scene_error("an 'irradiancemeter' must be nested inside the <shape> whose "
                          "irradiance it measures", loc)
    return sensor
