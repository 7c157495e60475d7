"""The plugins rdsl loads, their parameters, the kinds those take and Mitsuba 3's defaults.

A parameter's ``kind`` says which XML values it accepts:

============  ============================================================``float``     ``<float>`` (an ``<integer>`` is promoted, as in Mitsuba)
``integer``   ``<integer>``
``boolean``   ``<boolean>``
``string``    ``<string>``
``point``     ``<point>`` or ``<vector>``
``vector``    ``<vector>`` or ``<point>``
``transform`` ``<transform>``
``color``     ``<float>``, ``<rgb>``, ``<spectrum>`` or a ``<texture>`` (nested or ``<ref>``)
``ftex``      ``<float>`` or a ``<texture>`` (a scalar texture, e.g. roughness); also a
              constant ``<spectrum>`` or ``<rgb>`` (one value, or equal ones), as Mitsuba 3
              accepts any of its texture forms there
``fconst``    ``<float>`` or a constant ``<spectrum>`` / ``<rgb>``: a parameter Mitsuba 3 takes
              as a texture that rdsl takes as a constant (the polarizers' angles)
``ior``       ``<float>`` or ``<string>`` naming a dielectric (``"bk7"``, ``"water"``)
``spectrum``  ``<float>``, ``<rgb>`` or ``<spectrum>`` (a ``Spectrum`` param of a user plugin)
``vec3``      ``<vector>``, ``<point>`` or ``<rgb>`` (a ``Vec3`` param of a user plugin)
``unset``     nothing: a param the scene cannot set (``Vec2``, ``Vec4`` of a user plugin)
============  ============================================================
User plugins (runtime/plugins.py) get a :class:`PluginSpec` made from their ``param``
declarations, whose ``decl`` fields say where the plugin and each param are declared.

``REQUIRED`` marks a parameter without a default; ``None`` one that is optional and whose
absence the loader resolves (e.g. ``crop_width`` defaults to ``width``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

REQUIRED: Any = object()

KIND_ACCEPTS: dict[str, tuple[str, ...]] = {
    "float": ("float", "integer"),
    "integer": ("integer",),
    "boolean": ("boolean",),
    "string": ("string",),
    "point": ("point", "vector"),
    "vector": ("vector", "point"),
    "transform": ("transform",),
    "color": ("float", "integer", "rgb", "spectrum", "texture"),
    "ftex": ("float", "integer", "texture", "spectrum", "rgb"),
    "fconst": ("float", "integer", "spectrum", "rgb"),
    "ior": ("float", "integer", "string"),
    "spectrum": ("float", "integer", "rgb", "spectrum"),
    "vec3": ("vector", "point", "rgb"),
    "unset": (),
}

# what each kind takes, in words, for error messages
KIND_NAMES: dict[str, str] = {
    "float": "a float", "integer": "an integer", "boolean": "a boolean", "string": "a string",
    "point": "a point", "vector": "a vector", "transform": "a transform",
    "color": "a color (float, rgb, spectrum or texture)",
    "ftex": "a float or a texture (or a constant spectrum or rgb)",
    "fconst": "a constant float (a float, or a spectrum or rgb with one value)",
    "ior": "a float or a named IOR string", "spectrum": "a color (float, rgb or spectrum)",
    "vec3": "a vector, point or rgb",
    "unset": "nothing (it is not settable from a scene; give it a default in the plugin)"}


@dataclass(frozen=True)
class Param:
    """One accepted parameter: its kind, Mitsuba's default, and allowed values for strings;
    for a user plugin's param, its rdsl type and declaration (``file:line``)."""

    kind: str
    default: Any = None
    choices: tuple[str, ...] | None = None
    rdsl_type: str | None = None
    decl: str | None = None


@dataclass(frozen=True)
class PluginSpec:
    """An accepted plugin: its parameters and which nested objects it takes (min, max)."""

    category: str
    type: str
    params: dict[str, Param]
    children: dict[str, tuple[int, int]] = field(default_factory=dict)
    decl: Any = None  # a user plugin's runtime.plugins.PluginDecl (None: Mitsuba's schema)

    def texture_param(self, name: str | None) -> str | None:
        """The parameter a nested texture named ``name`` sets: its name, or for Mitsuba's
        bumpmap (its one texture, of any name) ANY_TEXTURE."""
        if name not in self.params and ANY_TEXTURE in self.params and self.decl is None:
            return ANY_TEXTURE
        return name


def P(kind: str, default: Any = None, choices: tuple[str, ...] | None = None) -> Param:
    return Param(kind, default, choices)


_DIST = P("string", "beckmann", ("beckmann", "ggx"))
_SHAPE = {"to_world": P("transform"), "flip_normals": P("boolean", False)}
_MESH = {**_SHAPE, "face_normals": P("boolean", False)}
_SHAPE_CHILDREN = {"bsdf": (0, 1), "emitter": (0, 1), "sensor": (0, 1)}
MANY = 1 << 62  # no upper bound on nested objects
_ROUGH = {"distribution": _DIST, "alpha": P("ftex", 0.1), "alpha_u": P("ftex"),
          "alpha_v": P("ftex"), "sample_visible": P("boolean", True)}
_CONDUCTOR = {"material": P("string", "none"), "eta": P("color"), "k": P("color"),
              "specular_reflectance": P("color", 1.0)}
# int_cauchy_b / ext_cauchy_b (an rdsl extension): Cauchy's B term in um^2, the IOR being
# the A term (n = A + B / l^2, l in um; stdlib/dispersion.rdsl)
_DIELECTRIC = {"int_ior": P("ior", "bk7"), "ext_ior": P("ior", "air"),
               "int_cauchy_b": P("float", 0.0), "ext_cauchy_b": P("float", 0.0),
               "specular_reflectance": P("color", 1.0),
               "specular_transmittance": P("color", 1.0)}
_PLASTIC = {"diffuse_reflectance": P("color", 0.5), "specular_reflectance": P("color", 1.0),
            "int_ior": P("ior", "polypropylene"), "ext_ior": P("ior", "air"),
            "nonlinear": P("boolean", False)}
_TEX = {"to_uv": P("transform")}
# principled's lobe weights: Mitsuba takes each as a float or a texture, default 0
_PRINCIPLED_LOBES = ("anisotropic", "metallic", "spec_trans", "spec_tint", "sheen",
                     "sheen_tint", "flatness", "clearcoat", "clearcoat_gloss")
_CAMERA = {
    "to_world": P("transform"), "fov": P("float"),
    "fov_axis": P("string", "x", ("x", "y", "diagonal", "smaller", "larger")),
    "focal_length": P("string"), "near_clip": P("float", 1e-2), "far_clip": P("float", 1e4),
    "focus_distance": P("float"), "shutter_open": P("float", 0.0),
    "shutter_close": P("float", 0.0),
}
# the parameter that a nested texture of any name sets (Mitsuba's bumpmap takes its one
# texture whatever its name)
ANY_TEXTURE = "texture"
_PERTURBED = {"flip_invalid_normals": P("boolean", True),
              "use_shadowing_function": P("boolean", True)}
_SENSOR_CHILDREN = {"film": (0, 1), "sampler": (0, 1)}

_SPECS = [
    # shapes
    PluginSpec("shape", "rectangle", dict(_SHAPE), _SHAPE_CHILDREN),
    PluginSpec("shape", "cube", dict(_MESH), _SHAPE_CHILDREN),
    # `triangulate` (an rdsl extension): render the triangle mesh, not the analytic shape
    PluginSpec("shape", "disk", {**_SHAPE, "triangulate": P("boolean", False)},
               _SHAPE_CHILDREN),
    PluginSpec("shape", "sphere", {**_SHAPE, "center": P("point"), "radius": P("float", 1.0),
                                   "triangulate": P("boolean", False)}, _SHAPE_CHILDREN),
    PluginSpec("shape", "cylinder", {**_SHAPE, "p0": P("point"), "p1": P("point"),
                                     "radius": P("float", 1.0)}, _SHAPE_CHILDREN),
    # Mitsuba 3's SDF grid (runtime/scene/sdfgrid.py); load_dict's `grid` becomes a file
    PluginSpec("shape", "sdfgrid", {"to_world": P("transform"),
                                    "filename": P("string", REQUIRED),
                                    "normals": P("string", "smooth", ("analytic", "smooth"))},
               _SHAPE_CHILDREN),
    # curves (runtime/scene/curves.py): Mitsuba's curve files, Embree's round curves
    *(PluginSpec("shape", t, {"to_world": P("transform"), "filename": P("string", REQUIRED)},
                 _SHAPE_CHILDREN) for t in ("linearcurve", "bsplinecurve")),
    PluginSpec("shape", "obj", {**_MESH, "filename": P("string", REQUIRED),
                                "flip_tex_coords": P("boolean", True)}, _SHAPE_CHILDREN),
    PluginSpec("shape", "ply", {**_MESH, "filename": P("string", REQUIRED),
                                "flip_tex_coords": P("boolean", False)}, _SHAPE_CHILDREN),
    PluginSpec("shape", "serialized", {**_MESH, "filename": P("string", REQUIRED),
                                       "shape_index": P("integer", 0)}, _SHAPE_CHILDREN),
    # shapes of shapes (runtime/scene/shape_build.py): a shapegroup is drawn only through its
    # instances (Embree instancing: its meshes are stored once); merge renders its shapes
    PluginSpec("shape", "shapegroup", {}, {"shape": (0, MANY)}),
    PluginSpec("shape", "instance", {"to_world": P("transform")}, {"shape": (1, 1)}),
    PluginSpec("shape", "merge", {}, {"shape": (0, MANY)}),
    # BSDFs
    PluginSpec("bsdf", "diffuse", {"reflectance": P("color", 0.5)}),
    PluginSpec("bsdf", "conductor", dict(_CONDUCTOR)),
    PluginSpec("bsdf", "roughconductor", {**_CONDUCTOR, **_ROUGH}),
    PluginSpec("bsdf", "dielectric", dict(_DIELECTRIC)),
    PluginSpec("bsdf", "thindielectric", dict(_DIELECTRIC)),
    PluginSpec("bsdf", "roughdielectric", {**_DIELECTRIC, **_ROUGH}),
    PluginSpec("bsdf", "plastic", dict(_PLASTIC)),
    # Mitsuba 3's roughplastic takes a constant alpha (it tabulates its transmittance once);
    # rdsl's evaluates it per call, so a texture works (an rdsl extension)
    PluginSpec("bsdf", "roughplastic", {**_PLASTIC, "distribution": _DIST,
                                        "alpha": P("ftex", 0.1),
                                        "sample_visible": P("boolean", True)}),
    # Mitsuba 3's polarized plastic: no `nonlinear`
    PluginSpec("bsdf", "pplastic", {**{k: v for k, v in _PLASTIC.items() if k != "nonlinear"},
                                    **_ROUGH}),
    # polarization: Mitsuba 3's angles are textures; rdsl takes constant degrees
    PluginSpec("bsdf", "polarizer", {"theta": P("fconst", 0.0),
                                     "transmittance": P("color", 1.0),
                                     "polarizing": P("boolean", True)}),
    PluginSpec("bsdf", "retarder", {"theta": P("fconst", 0.0), "delta": P("fconst", 90.0)}),
    PluginSpec("bsdf", "principled", {
        "base_color": P("color", 0.5), "roughness": P("ftex", 0.5), "eta": P("float"),
        "specular": P("float", 0.5), "diffuse_reflectance_sampling_rate": P("float", 1.0),
        "main_specular_sampling_rate": P("float", 1.0),
        "clearcoat_sampling_rate": P("float", 1.0),  # Mitsuba 3.9's code (its docs say 0)
        **{k: P("ftex", 0.0) for k in _PRINCIPLED_LOBES}}),
    PluginSpec("bsdf", "principledthin", {
        "base_color": P("color", 0.5), "roughness": P("ftex", 0.5), "eta": P("ftex", 1.5),
        "diff_trans": P("ftex", 0.0),
        **{f"{k}_sampling_rate": P("float", 1.0) for k in (
            "specular_reflectance", "specular_transmittance", "diffuse_reflectance",
            "diffuse_transmittance")},
        **{k: P("ftex", 0.0) for k in _PRINCIPLED_LOBES
           if k not in ("metallic", "clearcoat", "clearcoat_gloss")}}),
    # Mitsuba 3's hair (Chiang et al. 2016): the pigments or sigma_a, not both (hair.py)
    PluginSpec("bsdf", "hair", {
        "eumelanin": P("float"), "pheomelanin": P("float"), "sigma_a": P("color"),
        "scale": P("float", 1.0), "int_ior": P("ior", "amber"), "ext_ior": P("ior", "air"),
        "longitudinal_roughness": P("float", 0.3), "azimuthal_roughness": P("float", 0.3),
        "scale_tilt": P("float", 2.0)}),
    # a measured pBRDF (Baek et al. 2020) from a tensor file (core/tensorfile.py); Mitsuba
    # requires `wavelength` outside spectral variants
    PluginSpec("bsdf", "measured_polarized", {"filename": P("string", REQUIRED),
                                              "alpha_sample": P("float", 0.1),
                                              "wavelength": P("float", -1.0)}),
    # a pass-through (Mitsuba's null.cpp): light goes straight on, as mask's share
    PluginSpec("bsdf", "null", {}),
    PluginSpec("bsdf", "twosided", {}, {"bsdf": (1, 2)}),
    PluginSpec("bsdf", "mask", {"opacity": P("ftex", 0.5)}, {"bsdf": (1, 1)}),
    PluginSpec("bsdf", "blendbsdf", {"weight": P("ftex", REQUIRED)}, {"bsdf": (2, 2)}),
    # shading-frame perturbations of a nested BSDF (Mitsuba 3.9's PerturbedBSDF)
    PluginSpec("bsdf", "normalmap", {"normalmap": P("color", REQUIRED), **_PERTURBED},
               {"bsdf": (1, 1)}),
    PluginSpec("bsdf", "bumpmap", {ANY_TEXTURE: P("ftex", REQUIRED), "scale": P("float", 1.0),
                                   **_PERTURBED}, {"bsdf": (1, 1)}),
    # textures
    PluginSpec("texture", "bitmap", {
        **_TEX, "filename": P("string", REQUIRED),
        "filter_type": P("string", "bilinear", ("bilinear", "nearest")),
        "wrap_mode": P("string", "repeat", ("repeat", "mirror", "clamp")),
        "raw": P("boolean", False),
        # Mitsuba's storage format and GPU texture units: accepted, rdsl stores float32
        "format": P("string", "variant", ("variant", "fp16", "fp32")),
        "accel": P("boolean", True)}),
    PluginSpec("texture", "checkerboard", {**_TEX, "color0": P("color", 0.4),
                                           "color1": P("color", 0.2)}),
    # a PLY mesh's per-vertex or per-face attribute (runtime/scene/mesh_attributes.py)
    PluginSpec("texture", "mesh_attribute", {"name": P("string", REQUIRED),
                                             "scale": P("float", 1.0)}),
    # a 3-D texture: its nested volume at the point, in the volume's frame (the unit cube)
    PluginSpec("texture", "volume", {}, {"volume": (1, 1)}),
    # volumes (only as a `volume` texture's: rdsl has no participating media)
    PluginSpec("volume", "gridvolume", {
        "filename": P("string", REQUIRED), "to_world": P("transform"),
        "filter_type": P("string", "trilinear", ("trilinear", "nearest")),
        "wrap_mode": P("string", "clamp", ("repeat", "mirror", "clamp")),
        "raw": P("boolean", False), "use_grid_bbox": P("boolean", False)}),
    PluginSpec("volume", "constvolume", {"value": P("spectrum", 1.0),
                                         "to_world": P("transform")}),
    # emitters
    PluginSpec("emitter", "area", {"radiance": P("color", 1.0)}),
    PluginSpec("emitter", "point", {"intensity": P("color", 1.0), "position": P("point"),
                                    "to_world": P("transform")}),
    PluginSpec("emitter", "spot", {"intensity": P("color", 1.0),
                                   "cutoff_angle": P("float", 20.0), "beam_width": P("float"),
                                   "texture": P("color"), "to_world": P("transform")}),
    PluginSpec("emitter", "directional", {"irradiance": P("color", 1.0),
                                          "direction": P("vector"),
                                          "to_world": P("transform")}),
    PluginSpec("emitter", "constant", {"radiance": P("color", 1.0)}),
    # fov from `fov`/`fov_axis` or `focal_length` and the irradiance texture's aspect ratio
    # (a constant's is 1), as Mitsuba's parse_fov
    PluginSpec("emitter", "projector", {"irradiance": P("color", 1.0), "scale": P("float", 1.0),
                                        "to_world": P("transform"), "fov": P("float"),
                                        "fov_axis": _CAMERA["fov_axis"],
                                        "focal_length": P("string")}),
    PluginSpec("emitter", "envmap", {"filename": P("string", REQUIRED), "scale": P("float", 1.0),
                                     "to_world": P("transform"),
                                     "filter_type": P("string", "bilinear",
                                                      ("bilinear", "nearest")),
                                     # a sampling strategy (variance, not the expectation):
                                     # accepted, rdsl samples the map's luminance
                                     "mis_compensation": P("boolean", False)}),
    # integrators
    PluginSpec("integrator", "path", {"max_depth": P("integer", -1),
                                      "rr_depth": P("integer", 5),
                                      "hide_emitters": P("boolean", False)}),
    PluginSpec("integrator", "direct", {"emitter_samples": P("integer"),
                                        "bsdf_samples": P("integer"),
                                        "shading_samples": P("integer"),
                                        "hide_emitters": P("boolean", False)}),
    PluginSpec("integrator", "aov", {"aovs": P("string", REQUIRED)}, {"integrator": (0, 8)}),
    PluginSpec("integrator", "stokes", {}, {"integrator": (1, 1)}),
    PluginSpec("integrator", "moment", {}, {"integrator": (1, 8)}),
    # sensors, film, filters, samplers
    PluginSpec("sensor", "perspective", {**_CAMERA,
                                         "principal_point_offset_x": P("float", 0.0),
                                         "principal_point_offset_y": P("float", 0.0)},
               _SENSOR_CHILDREN),
    PluginSpec("sensor", "thinlens", {**_CAMERA, "aperture_radius": P("float", REQUIRED)},
               _SENSOR_CHILDREN),
    PluginSpec("sensor", "orthographic", {"to_world": P("transform"),
                                          "near_clip": P("float", 1e-2),
                                          "far_clip": P("float", 1e4),
                                          "shutter_open": P("float", 0.0),
                                          "shutter_close": P("float", 0.0)}, _SENSOR_CHILDREN),
    PluginSpec("sensor", "radiancemeter", {"to_world": P("transform"), "origin": P("point"),
                                           "direction": P("vector")}, _SENSOR_CHILDREN),
    PluginSpec("sensor", "irradiancemeter", {}, _SENSOR_CHILDREN),
    PluginSpec("film", "hdrfilm", {
        "width": P("integer", 768), "height": P("integer", 576),
        "crop_offset_x": P("integer", 0), "crop_offset_y": P("integer", 0),
        "crop_width": P("integer"), "crop_height": P("integer"),
        "file_format": P("string", "openexr", ("openexr", "exr", "rgbe", "pfm")),
        "pixel_format": P("string", "rgb", ("luminance", "luminance_alpha", "rgb", "rgba",
                                            "xyz", "xyza")),
        "component_format": P("string", "float16", ("float16", "float32", "uint32")),
        "sample_border": P("boolean", False)}, {"rfilter": (0, 1)}),
    PluginSpec("rfilter", "box", {"radius": P("float", 0.5)}),
    PluginSpec("rfilter", "tent", {"radius": P("float", 1.0)}),
    PluginSpec("rfilter", "gaussian", {"stddev": P("float", 0.5)}),
    PluginSpec("rfilter", "mitchell", {"B": P("float", 1.0 / 3.0), "C": P("float", 1.0 / 3.0)}),
    PluginSpec("rfilter", "catmullrom", {}),
    PluginSpec("rfilter", "lanczos", {"lobes": P("integer", 3)}),
    PluginSpec("sampler", "independent", {"sample_count": P("integer", 4),
                                          "seed": P("integer", 0)}),
    PluginSpec("sampler", "stratified", {"sample_count": P("integer", 4),
                                         "seed": P("integer", 0),
                                         "jitter": P("boolean", True)}),
    PluginSpec("sampler", "multijitter", {"sample_count": P("integer", 4),
                                          "seed": P("integer", 0),
                                          "jitter": P("boolean", True)}),
    PluginSpec("sampler", "orthogonal", {"sample_count": P("integer", 4),
                                         "seed": P("integer", 0), "strength": P("integer", 2),
                                         "jitter": P("boolean", True)}),
    PluginSpec("sampler", "ldsampler", {"sample_count": P("integer", 4),
                                        "seed": P("integer", 0)}),
]

SCHEMA: dict[tuple[str, str], PluginSpec] = {(s.category, s.type): s for s in _SPECS}

# What the <scene> itself accepts as direct children.
SCENE_CHILDREN = ("shape", "bsdf", "texture", "emitter", "integrator", "sensor")

AOV_TYPES = ("albedo", "depth", "position", "uv", "geo_normal", "sh_normal", "dp_du", "dp_dv",
             "duv_dx", "duv_dy", "prim_index", "shape_index")

# what Mitsuba 3's Bitmap reads (runtime/render/textures.py)
BITMAP_FORMATS = (".png", ".jpg", ".jpeg", ".exr", ".hdr", ".rgbe", ".pfm", ".bmp", ".tga",
                  ".ppm")


def plugin_types(category: str) -> list[str]:
    """The accepted ``type=`` values of one category, for error messages."""
    return [s.type for s in _SPECS if s.category == category]


def spec_for(category: str, ptype: str) -> PluginSpec | None:
    return SCHEMA.get((category, ptype))
