"""The compat suite's scenes beyond single BSDFs: combinators, textures, shapes from OBJ/PLY
with uvs and normals, emitters, integrators, references and includes, and the polarized
plugins in ``spectral_polarized`` (see _cases.py for the BSDFs)."""

from __future__ import annotations

from _cases import CHECKER_RGB, DIFFUSE, bitmap, bsdf, checker
from _sheet import Case, Sheet

RECT = '<shape type="rectangle">{T}{bsdf}</shape>'
BACK = (
    '<shape type="rectangle"><transform name="to_world"><rotate y="1" angle="180"/>'
    '<scale value="0.4"/><translate x="{X}" y="{Y}"/></transform>{bsdf}</shape>'
)
RED = bsdf("diffuse", '<rgb name="reflectance" value="0.8, 0.1, 0.1"/>')
GOLD = bsdf(
    "roughconductor", '<string name="material" value="Au"/>', '<float name="alpha" value="0.2"/>'
)


def shape(name: str, xml: str, xfail: str = "") -> Case:
    return Case(name, xml, shape=True, xfail=xfail)


COMBINATORS = (
    shape(
        "twosided.back", BACK.format(X="{X}", Y="{Y}", bsdf=f'<bsdf type="twosided">{RED}</bsdf>')
    ),
    shape(
        "twosided.two_bsdfs_front",
        RECT.replace("{bsdf}", f'<bsdf type="twosided">{RED}{GOLD}</bsdf>'),
    ),
    shape(
        "twosided.two_bsdfs_back",
        BACK.format(X="{X}", Y="{Y}", bsdf=f'<bsdf type="twosided">{RED}{GOLD}</bsdf>'),
    ),
    Case(
        "blendbsdf.weight_float", bsdf("blendbsdf", '<float name="weight" value="0.3"/>', RED, GOLD)
    ),
    Case("blendbsdf.weight_texture", bsdf("blendbsdf", checker("weight", 0.1, 0.9), RED, GOLD)),
    Case("blendbsdf.weight_bitmap", bsdf("blendbsdf", bitmap("weight", "tex_l.png"), RED, GOLD)),
    Case("mask.opacity_float", bsdf("mask", '<float name="opacity" value="0.3"/>', RED)),
    Case("mask.opacity_bitmap", bsdf("mask", bitmap("opacity", "tex_l.png"), RED)),
    Case("mask.opacity_checkerboard", bsdf("mask", checker("opacity", 0.2, 1.0), GOLD)),
    Case(
        "bumpmap.scale",
        bsdf(
            "bumpmap",
            bitmap("arbitrary", "height.png", '<boolean name="raw" value="true"/>'),
            '<float name="scale" value="0.5"/>',
            GOLD,
        ),
    ),
    Case(
        "normalmap.bitmap",
        bsdf(
            "normalmap",
            bitmap("normalmap", "normal.png", '<boolean name="raw" value="true"/>'),
            RED,
        ),
    ),
    Case("null.default", bsdf("null")),
)

_TEX = bsdf("diffuse", "{tex}")
TEXTURES = tuple(
    Case(f"{k}", _TEX.replace("{tex}", v))
    for k, v in {
        "bitmap.default": bitmap("reflectance"),
        "bitmap.nearest": bitmap(
            "reflectance", extra='<string name="filter_type" value="nearest"/>'
        ),
        "bitmap.mirror": bitmap(
            "reflectance",
            extra='<string name="wrap_mode" value="mirror"/>'
            '<transform name="to_uv"><scale value="2.5"/></transform>',
        ),
        "bitmap.clamp": bitmap(
            "reflectance",
            extra='<string name="wrap_mode" value="clamp"/>'
            '<transform name="to_uv"><scale value="2"/><translate x="-0.5"/></transform>',
        ),
        "bitmap.raw": bitmap("reflectance", extra='<boolean name="raw" value="true"/>'),
        "bitmap.exr": bitmap("reflectance", "tex_float.exr"),
        "bitmap.to_uv_rotate": bitmap(
            "reflectance",
            extra='<transform name="to_uv">'
            '<rotate z="1" angle="30"/><scale value="1.5"/></transform>',
        ),
        "checkerboard.spectrum": (
            '<texture type="checkerboard" name="reflectance">'
            '<spectrum name="color0" value="400:0.1, 700:0.8"/>'
            '<spectrum name="color1" value="0.3"/></texture>'
        ),
        "checkerboard.default": '<texture type="checkerboard" name="reflectance"/>',
        "checkerboard.to_uv": CHECKER_RGB.format(n="reflectance"),
    }.items()
)

TEXTURED = bsdf("diffuse", bitmap("reflectance"))
OBJ = '<shape type="obj"><string name="filename" value="$ASSETS/sphere.obj"/>{x}{T}{b}</shape>'
PLY = '<shape type="ply"><string name="filename" value="$ASSETS/sphere.ply"/>{x}{T}{b}</shape>'
ANISO = bsdf(
    "roughconductor",
    '<string name="material" value="Al"/>',
    '<float name="alpha_u" value="0.05"/>',
    '<float name="alpha_v" value="0.4"/>',
)
SHAPES = (
    shape("obj.uv_normals", OBJ.format(x="", T="{T}", b=TEXTURED)),
    shape(
        "obj.face_normals",
        OBJ.format(x='<boolean name="face_normals" value="true"/>', T="{T}", b=GOLD),
    ),
    shape(
        "obj.flip_tex_coords",
        OBJ.format(x='<boolean name="flip_tex_coords" value="false"/>', T="{T}", b=TEXTURED),
    ),
    shape("obj.anisotropic", OBJ.format(x="", T="{T}", b=ANISO)),
    shape("ply.uv_normals", PLY.format(x="", T="{T}", b=TEXTURED)),
    shape("ply.anisotropic", PLY.format(x="", T="{T}", b=ANISO)),
    shape(
        "ply.flip_normals",
        PLY.format(x='<boolean name="flip_normals" value="true"/>', T="{T}", b=bsdf("diffuse")),
    ),
    shape(
        "sphere.center_radius",
        '<shape type="sphere"><point name="center" x="{X}" y="{Y}" z="0"/>'
        f'<float name="radius" value="0.35"/>{TEXTURED}</shape>',
    ),
    shape(
        "cube.rotated",
        '<shape type="cube"><transform name="to_world"><scale value="0.3"/>'
        '<rotate x="0.70710678" y="0.70710678" angle="40"/><translate x="{X}" y="{Y}"/>'
        f"</transform>{TEXTURED}</shape>",
    ),
    shape(
        "rotate.unnormalized_axis",
        '<shape type="cube"><transform name="to_world">'
        '<scale value="0.25"/><rotate x="1" y="1" angle="40"/><translate x="{X}" y="{Y}"/>'
        f"</transform>{TEXTURED}</shape>",
        xfail="Mitsuba 3 does not normalize a <rotate> axis (x=1 y=1 shears and scales the "
        "cube, with a warning); rdsl normalizes it: RMSE 0.095 vs Mitsuba's 0.011",
    ),
    shape(
        "cylinder.p0_p1_radius",
        '<shape type="cylinder"><point name="p0" x="{X}" y="{Y}" z="-0.3"/>'
        '<point name="p1" x="{X}" y="{Y}" z="0.3"/><float name="radius" value="0.3"/>'
        '<transform name="to_world"><rotate x="1" angle="0"/></transform>'
        f"{TEXTURED}</shape>",
    ),
    shape(
        "disk.rotated",
        '<shape type="disk"><transform name="to_world"><scale value="0.4"/>'
        '<rotate x="1" angle="30"/><translate x="{X}" y="{Y}"/></transform>'
        f"{TEXTURED}</shape>",
    ),
    shape(
        "rectangle.anisotropic",
        '<shape type="rectangle"><transform name="to_world">'
        '<rotate z="1" angle="30"/><rotate x="1" angle="-20"/><scale value="0.4"/>'
        '<translate x="{X}" y="{Y}"/></transform>' + ANISO + "</shape>",
    ),
)


def emitter_rect(name: str, radiance: str) -> Case:
    return shape(
        name, f'<shape type="rectangle">{{T}}<emitter type="area">{radiance}</emitter></shape>'
    )


AREA = (
    emitter_rect("area.rgb", '<rgb name="radiance" value="2, 1, 0.5"/>'),
    emitter_rect("area.float", '<float name="radiance" value="1.5"/>'),
    emitter_rect("area.spectrum", '<spectrum name="radiance" value="1.2"/>'),
    emitter_rect(
        "area.spectrum_pairs", '<spectrum name="radiance" value="400:0.5, 550:2, 700:1"/>'
    ),
    emitter_rect("area.checkerboard", CHECKER_RGB.format(n="radiance")),
    emitter_rect("area.bitmap", bitmap("radiance")),
    shape(
        "area.sphere_with_bsdf",
        '<shape type="sphere">{T}<emitter type="area">'
        f'<rgb name="radiance" value="0.5, 1, 2"/></emitter>{GOLD}</shape>',
    ),
)

# four objects lit by the emitter under test (no other light)
LIT = (
    Case("diffuse", RED),
    Case("roughconductor", GOLD),
    Case("plastic", bsdf("plastic", '<rgb name="diffuse_reflectance" value="0.2, 0.4, 0.8"/>')),
    Case("textured", TEXTURED),
)


def lit(sheet: str, lights: str, xfail: dict[str, str] | None = None, strict: bool = True,
        **kw) -> Sheet:
    return Sheet(
        sheet,
        tuple(Case(f"{sheet}.{c.name}", c.xml, xfail=(xfail or {}).get(c.name, ""),
                   strict=strict) for c in LIT),
        lights=lights,
        **kw,
    )


POINT_SPOT = """
  <emitter type="point"><point name="position" x="-2" y="1.5" z="2.5"/>
    <spectrum name="intensity" value="400:4, 700:8"/></emitter>
  <emitter type="spot"><transform name="to_world"><lookat origin="2.5, 1, 3" target="0.5, 0, 0"/>
    </transform><rgb name="intensity" value="20, 18, 15"/>
    <float name="cutoff_angle" value="25"/><float name="beam_width" value="15"/></emitter>"""
DIRECTIONAL = """
  <emitter type="directional"><vector name="direction" x="0.5" y="-0.4" z="-1"/>
    <rgb name="irradiance" value="1.5, 1.3, 1"/></emitter>
  <emitter type="constant"><spectrum name="radiance" value="400:0.05, 700:0.2"/></emitter>"""
ENVMAP = """
  <emitter type="envmap"><string name="filename" value="$ASSETS/env.exr"/>
    <float name="scale" value="0.7"/>
    <transform name="to_world"><rotate y="1" angle="60"/><rotate x="1" angle="-30"/></transform>
  </emitter>"""
SPOT_TEXTURE = (
    """
  <emitter type="spot"><transform name="to_world"><lookat origin="0, 0.5, 4" target="0, 0, 0"/>
    </transform><float name="intensity" value="25"/><float name="cutoff_angle" value="30"/>
    """
    + bitmap("texture")
    + "</emitter>"
)
# a textured projector from above, a constant one (its fov from a focal length) from the left
PROJECTOR = (
    """
  <emitter type="projector"><transform name="to_world"><lookat origin="0.5, 1.5, 6" target="0, 0, 0"/>
    </transform><float name="scale" value="40"/><float name="fov" value="45"/>"""
    + bitmap("irradiance")
    + """</emitter>
  <emitter type="projector"><transform name="to_world"><lookat origin="-3, -1, 5" target="-0.5, 0, 0"/>
    </transform><rgb name="irradiance" value="0.6, 0.5, 0.3"/><float name="scale" value="12"/>
    <string name="focal_length" value="35mm"/></emitter>"""
)
DIRECT = (
    '<integrator type="direct"><integer name="emitter_samples" value="2"/>'
    '<integer name="bsdf_samples" value="3"/></integrator>'
)
PATH_RR = (
    '<integrator type="path"><integer name="max_depth" value="5"/>'
    '<integer name="rr_depth" value="2"/><boolean name="hide_emitters" value="true"/>'
    "</integrator>"
)

# references and includes: the tiles are at x = -1.5 .. 1.5, y = 0.5 (first row), -0.5
SHARED = (
    GOLD.replace('<bsdf type="roughconductor">', '<bsdf type="roughconductor" id="gold">')
    + '<texture type="checkerboard" id="chk"><rgb name="color0" value="0.9, 0.8, 0.2"/>'
    '<rgb name="color1" value="0.1, 0.2, 0.5"/><transform name="to_uv"><scale value="4"/>'
    "</transform></texture>"
)
LATER = (
    '<bsdf type="plastic" id="later"><rgb name="diffuse_reflectance" value="0.8, 0.4, 0.1"/></bsdf>'
)
# Mitsuba resolves an include's file names (meshes, textures, nested includes) against the
# main scene's folder and its <path>s (a <path> inside an included file has no effect there)
LEVEL1 = """<scene version="3.0.0">
  <include filename="inc/sub/level2.xml"/>
  <shape type="sphere"><transform name="to_world"><scale value="0.4"/><translate x="0.5" y="-0.5"/>
  </transform><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
    <string name="filename" value="textures/tex_l.png"/></texture></bsdf></shape>
</scene>"""
LEVEL2 = """<scene version="3.0.0">
  <shape type="sphere"><transform name="to_world"><scale value="0.4"/><translate x="1.5" y="-0.5"/>
  </transform><bsdf type="diffuse"><texture type="bitmap" name="reflectance">
    <string name="filename" value="tex_rgb.png"/></texture></bsdf></shape>
</scene>"""
STRUCTURE = (
    Case("ref.bsdf_first", '<ref id="gold"/>'),
    Case("ref.bsdf_second", '<ref id="gold"/>'),
    Case("ref.texture_diffuse", bsdf("diffuse", '<ref name="reflectance" id="chk"/>')),
    Case("ref.texture_blend_weight", bsdf("blendbsdf", '<ref name="weight" id="chk"/>', RED, GOLD)),
    Case("ref.forward", '<ref id="later"/>'),
    Case("ref.texture_named_twice", bsdf("plastic", '<ref name="diffuse_reflectance" id="chk"/>')),
    shape("include.relative_to_scene", ""),
    shape("include.nested_via_path", ""),
)

POLARIZER = '<bsdf type="polarizer">{p}</bsdf>'


def filters(name: str, first: str, second: str = "", middle: str = "") -> Case:
    """Polarizing filters (rectangles) stacked in front of the tile's backdrop."""
    layers = [x for x in (first, middle, second) if x]
    xml = "".join(
        f'<shape type="rectangle"><transform name="to_world"><scale value="0.45"/>'
        f'<translate x="{{X}}" y="{{Y}}" z="{0.6 * (k + 1)}"/></transform>{b}</shape>'
        for k, b in enumerate(layers)
    )
    return shape(name, xml)


def pol(*params: str) -> str:
    return POLARIZER.format(p="".join(params))


POLARIZED = (
    filters("polarizer.single", pol()),
    filters("polarizer.theta_float", pol(), pol('<float name="theta" value="60"/>')),
    filters("polarizer.theta_spectrum", pol(), pol('<spectrum name="theta" value="45"/>')),
    filters("polarizer.crossed", pol('<float name="theta" value="90"/>'), pol()),
    filters("polarizer.transmittance", pol('<rgb name="transmittance" value="0.9, 0.5, 0.3"/>')),
    filters(
        "polarizer.not_polarizing",
        pol('<boolean name="polarizing" value="false"/>'),
        pol('<float name="theta" value="90"/>'),
    ),
    filters(
        "retarder.quarter_wave",
        pol(),
        pol('<float name="theta" value="90"/>'),
        '<bsdf type="retarder"><float name="theta" value="45"/>'
        '<float name="delta" value="90"/></bsdf>',
    ),
    filters(
        "retarder.half_wave_spectrum",
        pol(),
        pol('<float name="theta" value="90"/>'),
        '<bsdf type="retarder"><spectrum name="theta" value="22.5"/>'
        '<spectrum name="delta" value="180"/></bsdf>',
    ),
)
POLARIZED_BSDFS = (
    Case("pplastic.polarized", bsdf("pplastic", '<float name="alpha" value="0.2"/>')),
    Case("conductor.polarized", bsdf("conductor", '<string name="material" value="Au"/>')),
    Case("roughconductor.polarized", GOLD),
    Case("dielectric.polarized", bsdf("dielectric")),
    Case("roughdielectric.polarized", bsdf("roughdielectric", '<float name="alpha" value="0.2"/>')),
    Case("plastic.polarized", bsdf("plastic")),
    Case("diffuse.polarized", RED),
    Case("thindielectric.polarized", bsdf("thindielectric")),
)

LOOK = (
    '<transform name="to_world"><lookat origin="0, 0, 12" target="0, 0, 0" up="0, 1, 0"/>'
    "</transform>"
)
THINLENS = (
    f'<sensor type="thinlens"><float name="fov" value="12"/>{LOOK}'
    '<string name="fov_axis" value="smaller"/>'
    '<float name="aperture_radius" value="0.3"/><float name="focus_distance" value="10"/>'
    "{film}</sensor>"
)
ORTHOGRAPHIC = (
    '<sensor type="orthographic"><transform name="to_world"><scale x="2.2" y="2.2"/>'
    '<lookat origin="0, 0, 12" target="0, 0, 0" up="0, 1, 0"/></transform>'
    '<float name="near_clip" value="2"/>{film}</sensor>'
)
PERSPECTIVE = (
    f'<sensor type="perspective"><string name="focal_length" value="90mm"/>{LOOK}'
    '<float name="near_clip" value="5"/>'
    '<float name="principal_point_offset_x" value="0.1"/>{film}</sensor>'
)


def filtered(sheet: str, rfilter: str) -> Sheet:
    return Sheet(sheet, tuple(Case(f"{sheet}.{c.name}", c.xml) for c in LIT), rfilter=rfilter)


def sensor(sheet: str, xml: str, **kw) -> Sheet:
    return Sheet(sheet, tuple(Case(f"{sheet}.{c.name}", c.xml) for c in LIT), sensor=xml, **kw)


# a Float parameter from a colour texture: Mitsuba's eval_1 (the blend weight)
RG_CHECKER = (
    '<texture type="checkerboard" name="weight"><rgb name="color0" value="0.9, 0.1, 0.1"/>'
    '<rgb name="color1" value="0.1, 0.9, 0.1"/><transform name="to_uv"><scale value="4"/>'
    "</transform></texture>"
)
EVAL_1 = (
    Case("checkerboard.eval_1_rgb", bsdf("blendbsdf", RG_CHECKER, RED, GOLD)),
    Case("bitmap.eval_1_rgb", bsdf("blendbsdf", bitmap("weight"), RED, GOLD)),
)

SCENE_SHEETS: list[Sheet] = [
    Sheet("combinators", COMBINATORS),
    Sheet("textures", TEXTURES, obj=RECT, cols=5),
    Sheet("shapes", SHAPES),
    Sheet("area", AREA),
    lit("point_spot", POINT_SPOT),
    lit("directional_constant", DIRECTIONAL),
    lit("envmap", ENVMAP),
    lit("spot_texture", SPOT_TEXTURE),
    lit("projector", PROJECTOR),
    lit("projector_spectral", PROJECTOR, variant="spectral"),
    Sheet("direct", tuple(Case(f"direct.{c.name}", c.xml) for c in LIT), integrator=DIRECT),
    Sheet("path_rr", tuple(Case(f"path_rr.{c.name}", c.xml) for c in LIT), integrator=PATH_RR),
    Sheet(
        "structure",
        STRUCTURE,
        extra=SHARED + '<path value="textures"/><include filename="inc/level1.xml"/>',
        after=LATER,
        files={
            "inc/level1.xml": LEVEL1,
            "inc/sub/level2.xml": LEVEL2,
            "textures/tex_rgb.png": "$ASSETS/tex_rgb.png",
            "textures/tex_l.png": "$ASSETS/tex_l.png",
        },
    ),
    Sheet(
        "spectral",
        tuple(Case(f"spectral.{c.name}", c.xml) for c in DIFFUSE[2:6])
        + (Case("spectral.conductor.au", GOLD), Case("spectral.dielectric", bsdf("dielectric"))),
        variant="spectral",
        cols=3,
    ),
    Sheet("polarized", POLARIZED + POLARIZED_BSDFS, variant="spectral_polarized"),
    Sheet("eval_1", EVAL_1, cols=2),
    sensor("thinlens", THINLENS),
    sensor("orthographic", ORTHOGRAPHIC, rfilter='<rfilter type="gaussian"/>'),
    filtered("mitchell", '<rfilter type="mitchell"><float name="B" value="0.2"/>'
             '<float name="C" value="0.4"/></rfilter>'),
    filtered("catmullrom", '<rfilter type="catmullrom"/>'),
    filtered("lanczos", '<rfilter type="lanczos"/>'),
    sensor(
        "perspective",
        PERSPECTIVE,
        rfilter='<rfilter type="tent"><float name="radius" value="0.8"/></rfilter>',
    ),
]

UNSUPPORTED_SCENE: tuple[Case, ...] = ()
