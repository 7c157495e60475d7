"""The loader's per-category checks and derived values of BSDFs, textures, emitters,
integrators, sensors, films, reconstruction filters and samplers (shapes: shape_build.py).

:class:`Finishers` is a mixin of the loader's builder (loader.py), which calls
``finish_<category>(obj, node, objects)`` once a plugin's parameters and nested objects are
collected; it uses the builder's ``what``, ``file`` and ``default``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ...compiler.ir import Loc
from ...core.tensorfile import PBrdf, TensorFileError, read_pbrdf
from . import transform as xf
from .camera import finish_projector
from .errors import scene_error
from .hair import resolve_hair
from .mesh_attributes import PREFIXES
from .nodes import param_loc as _loc
from .principled import resolve_principled
from .reads import memoized
from .samplers import finish_sampler
from .schema import AOV_TYPES, BITMAP_FORMATS
from .sensors import METERS, finish_sensor
from .spectra import Color, conductor_ior
from .volumes import load_volume_grid
from .xml import ObjectNode

if TYPE_CHECKING:
    from .loader import Plugin, Sensor

# the largest Cauchy B term accepted (um^2): glasses are below 0.02, so a larger value is a
# unit mistake (nm^2) rather than a material
MAX_CAUCHY_B = 1.0
MAX_PIXELS = 1 << 30  # a film's pixels (cells and samples are indexed with 32-bit Int)


def _read_pbrdf(path: Path, loc: Loc | None) -> PBrdf:
    """The pBRDF table of ``path`` (a reload reuses an unchanged file's), or an error naming
    the file and what is wrong with it, at the XML's ``filename``."""
    try:
        return memoized(path, "pbrdf", lambda: read_pbrdf(path))
    except TensorFileError as e:
        raise scene_error(f"measured_polarized: {e}", loc) from None


class Finishers:
    """``finish_<category>`` of every category but shapes (a mixin of the loader's builder)."""

    def finish_bsdf(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = [b for b, _ in objects.get("bsdf", [])]
        if obj.decl is not None:  # a user plugin: its params are its own, not Mitsuba's
            return
        if obj.type == "measured_polarized":
            path = self.file(node, "filename", "pBRDF")
            p["filename"], p["table"] = str(path), _read_pbrdf(path, _loc(node, "filename"))
            if not p["alpha_sample"] > 0.0:  # its GGX sampling would give NaN pdfs
                raise scene_error(f"{self.what(node)}: 'alpha_sample' is {p['alpha_sample']:g}; "
                                  "the roughness of its importance sampling must be > 0",
                                  _loc(node, "alpha_sample"))
        if obj.type == "principled":
            resolve_principled(p, lambda k: _loc(node, k) is not node.loc, self.what(node),
                               lambda k: _loc(node, k))
        if obj.type == "hair":
            resolve_hair(p, lambda k: _loc(node, k) is not node.loc, self.what(node),
                         lambda k: _loc(node, k))
        if "material" in p:
            given = [k for k in ("eta", "k") if p[k] is not None]
            if given and "material" in node.props:
                raise scene_error(f"{self.what(node)}: give either 'material' or 'eta'/'k', "
                                  "not both", _loc(node, "material"))
            if given:
                p["eta"] = p["eta"] if p["eta"] is not None else Color.gray(0.0)
                p["k"] = p["k"] if p["k"] is not None else Color.gray(1.0)
            else:
                p["eta"], p["k"] = conductor_ior(p["material"], _loc(node, "material"))
        if "alpha_u" in p:
            has_u, has_v = p["alpha_u"] is not None, p["alpha_v"] is not None
            if has_u != has_v:
                raise scene_error(f"{self.what(node)}: give both 'alpha_u' and 'alpha_v'",
                                  _loc(node, "alpha_u" if has_u else "alpha_v"))
            if has_u and "alpha" in node.props:
                raise scene_error(f"{self.what(node)}: give either 'alpha' or "
                                  "'alpha_u'/'alpha_v', not both", _loc(node, "alpha"))
            # isotropic (`alpha`): alpha_u/alpha_v stay unset, so that the plugin's own
            # isotropic case reads `alpha` for both axes and `<id>.alpha` is one parameter,
            # as in Mitsuba's mi.traverse (`alpha_u`/`alpha_v` only when both are given)
        if "int_ior" in p:
            p["eta"] = p["int_ior"] / p["ext_ior"] if p["ext_ior"] > 0 else 0.0
        for side in ("int", "ext"):
            b = p.get(f"{side}_cauchy_b")
            if b is not None and not 0.0 <= b <= MAX_CAUCHY_B:
                raise scene_error(
                    f"{self.what(node)}: '{side}_cauchy_b' is {b:g}; Cauchy's B term is in "
                    f"um^2 and must lie in [0, {MAX_CAUCHY_B:g}] (BK7: 0.00420, dense flint "
                    "glass: ~0.014; a value in nm^2 is 10^6 times too large)",
                    _loc(node, f"{side}_cauchy_b"))

    def finish_texture(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        if obj.type == "volume" and obj.decl is None:
            obj.children = [v for v, _ in objects["volume"]]
            return
        if obj.type == "mesh_attribute" and obj.decl is None:
            if not p["name"].startswith(PREFIXES) or p["name"] in PREFIXES:
                raise scene_error(f"mesh_attribute: 'name' is '{p['name']}'; an attribute is "
                                  "named vertex_<name> (interpolated across each triangle) or "
                                  "face_<name> (one value per triangle), such as vertex_color",
                                  _loc(node, "name"))
            return
        if p.get("to_uv") is None and (obj.decl is None or "to_uv" in p):
            p["to_uv"] = xf.identity()
        if obj.type == "bitmap" and obj.decl is None:
            path = self.file(node, "filename", "texture")
            if path.suffix.lower() not in BITMAP_FORMATS:
                raise scene_error(f"bitmap: image format '{path.suffix}' of '{p['filename']}' "
                                  f"is not supported; accepted: {', '.join(BITMAP_FORMATS)}",
                                  _loc(node, "filename"))
            p["filename"] = str(path)

    def grid_file(self, node: ObjectNode, p: dict, load: Callable[[Path], Any]) -> Any:
        """``load(path)`` of the grid file ``filename`` (an sdfgrid's, a gridvolume's), which
        becomes its path; or an error naming the file and why, at the XML's ``filename``."""
        path = self.file(node, "filename", "grid")
        try:
            out = load(path)
        except (ValueError, OSError) as e:
            why = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise scene_error(f"{self.what(node)}: cannot load grid file "
                              f"'{p['filename']}' ({path}): {why}",
                              _loc(node, "filename")) from None
        p["filename"] = str(path)
        return out

    def finish_volume(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        if p["to_world"] is None:
            p["to_world"] = xf.identity()
        if obj.type == "gridvolume":
            self.grid_file(node, p, load_volume_grid)
        elif getattr(p["value"], "rgb", None) is None:
            raise scene_error("constvolume: 'value' must be a float, rgb or spectrum",
                              _loc(node, "value"))

    def finish_emitter(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        if obj.decl is not None:
            return
        if "to_world" in p and p["to_world"] is None:
            p["to_world"] = xf.identity()
        if obj.type == "point" and p["position"] is not None:
            if "to_world" in node.props:
                raise scene_error("point emitter: give either 'position' or 'to_world'",
                                  _loc(node, "position"))
            p["to_world"] = xf.translate(p["position"])
        if obj.type == "point":
            p["position"] = p["to_world"][:3, 3].copy()
        if obj.type == "projector":
            finish_projector(p, lambda k: _loc(node, k))
        if obj.type == "spot" and p["beam_width"] is None:
            p["beam_width"] = p["cutoff_angle"] * 0.75
        if obj.type == "directional":
            if p["direction"] is not None:
                if "to_world" in node.props:
                    raise scene_error("directional emitter: give either 'direction' or "
                                      "'to_world'", _loc(node, "direction"))
                d = p["direction"]
                if not np.any(d):
                    raise scene_error("directional emitter: 'direction' is zero",
                                      _loc(node, "direction"))
                p["to_world"] = xf.look_at([0, 0, 0], d)
            p["direction"] = p["to_world"][:3, 2] / np.linalg.norm(p["to_world"][:3, 2])
        if obj.type == "envmap":
            path = self.file(node, "filename", "environment map")
            if path.suffix.lower() not in BITMAP_FORMATS:
                raise scene_error(f"envmap: image format '{path.suffix}' is not supported; "
                                  f"accepted: {', '.join(BITMAP_FORMATS)}", _loc(node, "filename"))
            p["filename"] = str(path)

    def finish_integrator(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = [i for i, _ in objects.get("integrator", [])]
        if obj.decl is not None:  # a user's plugin (or one given as a file): its own params
            return
        p["nested_names"] = [ch.name or f"_arg_{k}"
                             for k, (_, ch) in enumerate(objects.get("integrator", []))]
        if obj.type == "path":
            if p["max_depth"] < -1:
                raise scene_error("path: 'max_depth' must be -1 (infinite) or >= 0",
                                  _loc(node, "max_depth"))
            if p["rr_depth"] <= 0:
                raise scene_error("path: 'rr_depth' must be > 0", _loc(node, "rr_depth"))
        elif obj.type == "direct":  # Mitsuba's checks of direct.cpp
            ss = p["shading_samples"]
            if ss is not None and (p["emitter_samples"] is not None
                                   or p["bsdf_samples"] is not None):
                raise scene_error("direct: cannot specify both 'shading_samples' and "
                                  "('emitter_samples' and/or 'bsdf_samples')", node.loc)
            for k in ("emitter_samples", "bsdf_samples"):
                if p[k] is None:
                    p[k] = ss if ss is not None else 1
                if p[k] < 0:
                    raise scene_error(f"direct: '{k}' must be >= 0", _loc(node, k))
            if p["emitter_samples"] + p["bsdf_samples"] == 0:
                raise scene_error("direct: must have at least 1 BSDF or emitter sample",
                                  node.loc)
        elif obj.type == "aov":
            aovs = []
            for item in (s.strip() for s in p["aovs"].split(",")):
                name, sep, kind = item.partition(":")
                if not sep or not name.strip() or kind.strip() not in AOV_TYPES:
                    raise scene_error(f"aov: bad entry '{item}' in 'aovs'; write name:type with "
                                      f"type one of {', '.join(AOV_TYPES)}", _loc(node, "aovs"))
                aovs.append((name.strip(), kind.strip()))
            p["aov_list"] = aovs

    def finish_sensor(self, obj: Sensor, node: ObjectNode, objects: dict) -> None:
        one = {"width": 1, "height": 1} if obj.type in METERS else {}  # a one-pixel film
        obj.film = objects["film"][0][0] if objects["film"] else self.default("film", "hdrfilm",
                                                                                **one)
        obj.sampler = objects["sampler"][0][0] if objects["sampler"] else None
        finish_sensor(obj, lambda k: _loc(node, k))

    def finish_film(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        p = obj.params
        obj.children = []
        p["rfilter"] = (objects["rfilter"][0][0] if objects["rfilter"]
                        else self.default("rfilter", "gaussian"))
        for k in ("width", "height"):
            if p[k] <= 0:
                raise scene_error(f"hdrfilm: '{k}' must be positive", _loc(node, k))
        p["crop_width"] = p["width"] if p["crop_width"] is None else p["crop_width"]
        p["crop_height"] = p["height"] if p["crop_height"] is None else p["crop_height"]
        for axis, size in (("x", "width"), ("y", "height")):
            off, crop = p[f"crop_offset_{axis}"], p[f"crop_{size}"]
            if off < 0 or crop <= 0 or off + crop > p[size]:
                raise scene_error(f"hdrfilm: invalid crop window: crop_offset_{axis}={off} and "
                                  f"crop_{size}={crop} do not fit in {size}={p[size]}",
                                  _loc(node, f"crop_{size}" if f"crop_{size}" in node.props
                                       else f"crop_offset_{axis}"))
        if p["crop_width"] * p["crop_height"] > MAX_PIXELS:  # the kernels index with Int
            raise scene_error(f"hdrfilm: {p['crop_width']} x {p['crop_height']} pixels is "
                              f"more than the {MAX_PIXELS} (32768 x 32768) rdsl renders",
                              _loc(node, "width"))

    def finish_rfilter(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        for k, v in obj.params.items():
            if k in ("B", "C"):  # mitchell's: any finite value (Catmull-Rom is B = 0)
                if not np.isfinite(v):
                    raise scene_error(f"rfilter '{obj.type}': '{k}' must be finite",
                                      _loc(node, k))
            elif not 0 < v < math.inf:  # NaN too
                raise scene_error(f"rfilter '{obj.type}': '{k}' must be positive and finite",
                                  _loc(node, k))

    def finish_sampler(self, obj: Plugin, node: ObjectNode, objects: dict) -> None:
        finish_sampler(obj, lambda k: _loc(node, k))
