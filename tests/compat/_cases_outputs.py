"""The compat suite's film and integrator outputs: crop windows and pixel formats of the
``hdrfilm``, the ``mono`` variant, and the integrators whose image is more than a radiance
(``aov``, ``depth``, ``moment``, and ``stokes`` in the polarized variants), compared channel
by channel: each output sheet compares its ``channels`` (indices into the image, which rdsl
and Mitsuba 3 lay out alike: the colour, then each AOV's channels in order).  Sheets of one
scene (the AOVs of one render) are rendered once (_sheet.measure)."""

from __future__ import annotations

from _cases import CONDUCTOR, DIELECTRIC, DIFFUSE, ROUGHPLASTIC, bitmap, bsdf
from _cases_scene import (ENVMAP, GOLD, LIT, OBJ, ORTHOGRAPHIC, PERSPECTIVE, PLY, POLARIZED,
                          POLARIZED_BSDFS, RED, TEXTURED, shape)
from _sheet import Case, Sheet


def renamed(prefix: str, cs: tuple[Case, ...]) -> tuple[Case, ...]:
    return tuple(Case(f"{prefix}.{c.name}", c.xml, c.shape, c.xfail, c.strict) for c in cs)


# ----------------------------------------------------------------------- the mono variant
# under the envmap of the envmap sheet (_cases_scene.py): one kernel for both
MONO = renamed("mono", (DIFFUSE[2], DIFFUSE[6], CONDUCTOR[1], DIELECTRIC[0], ROUGHPLASTIC[0],
                        ROUGHPLASTIC[3]))

# ----------------------------------------------------------------------------- the film
# crop windows that cut every tile of a row of four (96 x 24 pixels), the lenses' and
# filters' of their sheets (_cases_scene.py): rdsl's crop must be that window of the image
CROPS = {"crop.orthographic": (ORTHOGRAPHIC, '<rfilter type="gaussian"/>', (10, 5, 70, 15)),
         "crop.perspective": (PERSPECTIVE,
                              '<rfilter type="tent"><float name="radius" value="0.8"/></rfilter>',
                              (13, 3, 66, 19))}


def crop_sheet(name: str) -> Sheet:
    xml, rfilter, window = CROPS[name]
    return Sheet(name, renamed(name, LIT), sensor=xml, rfilter=rfilter, crop=window)


LUMINANCE = '<string name="pixel_format" value="luminance"/>'
CATMULLROM = '<rfilter type="catmullrom"/>'  # the catmullrom sheet's: its kernel is this one's

# ---------------------------------------------------------------------------- the AOVs
# shapes with their own uvs, normals and frames, and BSDFs whose albedo differs
AOV_CASES = (
    shape("sphere", f'<shape type="sphere">{{T}}{TEXTURED}</shape>'),
    shape("obj", OBJ.format(x="", T="{T}", b=TEXTURED)),
    shape("ply_face_normals",
          PLY.format(x='<boolean name="face_normals" value="true"/>', T="{T}", b=RED)),
    shape("rectangle",
          '<shape type="rectangle"><transform name="to_world"><rotate z="1" angle="30"/>'
          '<rotate x="1" angle="-35"/><scale value="0.4"/><translate x="{X}" y="{Y}"/>'
          f'</transform>{bsdf("diffuse", bitmap("reflectance"))}</shape>'),
    shape("cube",
          '<shape type="cube"><transform name="to_world"><scale value="0.3"/>'
          '<rotate x="0.70710678" y="0.70710678" angle="40"/><translate x="{X}" y="{Y}"/>'
          f"</transform>{GOLD}</shape>"),
    shape("disk",
          '<shape type="disk"><transform name="to_world"><scale value="0.4"/>'
          '<rotate y="1" angle="40"/><translate x="{X}" y="{Y}"/></transform>'
          f'{bsdf("plastic", bitmap("diffuse_reflectance"))}</shape>'),
    shape("cylinder",
          '<shape type="cylinder"><point name="p0" x="{X}" y="{Y}" z="-0.3"/>'
          '<point name="p1" x="{X}" y="{Y}" z="0.3"/><float name="radius" value="0.3"/>'
          f"{RED}</shape>"),
    shape("sphere_conductor",
          '<shape type="sphere"><transform name="to_world"><scale value="0.35"/>'
          '<rotate x="1" angle="50"/><translate x="{X}" y="{Y}"/></transform>'
          f'{bsdf("conductor")}</shape>'),
)
PATH = '<integrator type="path"><integer name="max_depth" value="6"/></integrator>'
AOVS = {"depth": 1, "position": 3, "uv": 2, "geo_normal": 3, "sh_normal": 3, "albedo": 3,
        "dp_du": 3, "dp_dv": 3}
AOV = ('<integrator type="aov"><string name="aovs" value="'
       + ",".join(f"a{k}:{t}" for k, t in enumerate(AOVS)) + f'"/>{PATH}</integrator>')


def aov_sheets() -> list[Sheet]:
    """One sheet per AOV of one render (the nested path tracer's radiance first)."""
    out, first = [Sheet("aov.radiance", renamed("aov.radiance", AOV_CASES), integrator=AOV)], 3
    for kind, n in AOVS.items():
        out.append(Sheet(f"aov.{kind}", renamed(f"aov.{kind}", AOV_CASES), integrator=AOV,
                         channels=tuple(range(first, first + n))))
        first += n
    return out


# the moment integrator: the XYZ colour and its square, after the radiance
MOMENT = f'<integrator type="moment">{PATH}</integrator>'
# the Stokes vector S0..S3 (three channels each) after the colour (Y alone in mono)
STOKES = f'<integrator type="stokes">{PATH}</integrator>'
STOKES_CASES = tuple(c for c in POLARIZED + POLARIZED_BSDFS if c.name in (
    "polarizer.single", "polarizer.theta_float", "retarder.quarter_wave",
    "retarder.half_wave_spectrum", "conductor.polarized", "roughconductor.polarized",
    "dielectric.polarized", "pplastic.polarized"))


def stokes_sheets(variant: str, first: int) -> list[Sheet]:
    return [Sheet(f"stokes.{variant}.S{k}", renamed(f"stokes.{variant}.S{k}", STOKES_CASES),
                  variant=variant, integrator=STOKES,
                  channels=tuple(range(first + 3 * k, first + 3 * k + 3))) for k in range(4)]


OUTPUT_SHEETS: list[Sheet] = [
    Sheet("mono", MONO, variant="mono", cols=3, lights=ENVMAP),
    *(crop_sheet(n) for n in CROPS),
    Sheet("luminance", renamed("luminance", LIT), film=LUMINANCE, rfilter=CATMULLROM),
    *aov_sheets(),
    Sheet("depth", renamed("depth", AOV_CASES), integrator='<integrator type="depth"/>'),
    Sheet("moment.xyz", renamed("moment.xyz", AOV_CASES), integrator=MOMENT, channels=(3, 4, 5)),
    Sheet("moment.m2", renamed("moment.m2", AOV_CASES), integrator=MOMENT, channels=(6, 7, 8)),
    *stokes_sheets("spectral_polarized", 3),
    *stokes_sheets("mono_polarized", 1),
]
