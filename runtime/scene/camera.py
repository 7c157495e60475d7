"""A camera's horizontal field of view from its ``fov``/``fov_axis`` or ``focal_length``."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from ...compiler.ir import Loc
from .errors import scene_error


def fov_x(p: dict[str, Any], aspect: float, loc: Callable[[str], Loc]) -> float:
    """Mitsuba's ``parse_fov``: the horizontal field of view in degrees, from a sensor's
    resolved params ``p``; ``loc(name)`` is the line of parameter ``name``, for errors."""
    if p["fov"] is not None and p["focal_length"] is not None:
        raise scene_error("give either 'fov' or 'focal_length', not both", loc("fov"))
    if p["fov"] is not None:
        fov, axis = p["fov"], p["fov_axis"]
        if not 0 < fov < 180:  # NaN too
            raise scene_error(f"'fov' must be between 0 and 180 degrees, got {fov:g}",
                              loc("fov"))
        if axis == "smaller":
            axis = "y" if aspect > 1 else "x"
        elif axis == "larger":
            axis = "x" if aspect > 1 else "y"
    else:
        f = p["focal_length"] or "50mm"
        try:
            value = float(f.removesuffix("mm"))
        except ValueError:
            raise scene_error(f"cannot parse focal_length '{f}' (write e.g. \"50mm\")",
                              loc("focal_length")) from None
        fov, axis = 2 * math.degrees(math.atan(math.hypot(36, 24) / (2 * value))), "diagonal"
    t = math.tan(math.radians(fov) / 2)
    if axis == "x":
        out = fov
    elif axis == "y":
        out = 2 * math.degrees(math.atan(t * aspect))
    else:
        out = 2 * math.degrees(math.atan(t / math.sqrt(1 + 1 / (aspect * aspect))))
    if not 0 < out < 180:
        raise scene_error(f"the horizontal field of view ({out:g} degrees) must be in "
                          "(0, 180)", loc("fov"))
    return out


def texture_resolution(tex: Any, loc: Loc) -> tuple[int, int]:
    """Mitsuba's ``Texture::resolution``: a bitmap's (width, height), (1, 1) for any other
    texture or a constant."""
    if getattr(tex, "category", None) != "texture" or tex.type != "bitmap" or tex.decl:
        return 1, 1
    from ..render.textures import load_bitmap  # memoized: a recorded load decodes it once

    try:
        h, w = load_bitmap(tex.params["filename"], bool(tex.params["raw"])).shape[:2]
    except (OSError, ValueError, SyntaxError) as e:
        raise scene_error(f"bitmap: cannot load '{tex.params['filename']}': {e}",
                          tex.loc) from None
    except RuntimeError as e:  # Pillow missing
        raise scene_error(f"bitmap: {e}", tex.loc) from None
    return w, h


def finish_projector(p: dict[str, Any], loc: Callable[[str], Loc]) -> None:
    """Mitsuba's projector: its horizontal field of view (``fov_x``) and aspect ratio from
    the irradiance texture's resolution, and a positive ``scale``."""
    if not p["scale"] >= 0:
        raise scene_error(f"projector: 'scale' must be >= 0, got {p['scale']:g}", loc("scale"))
    if p["fov"] is None and p["fov_axis"] != "x":  # Mitsuba: an unreferenced property
        raise scene_error("projector: 'fov_axis' applies to 'fov' only (give 'fov' too)",
                          loc("fov_axis"))
    w, h = texture_resolution(p["irradiance"], loc("irradiance"))
    p["aspect"] = w / h
    p["fov_x"] = fov_x(p, p["aspect"], loc)
